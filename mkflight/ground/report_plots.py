"""The flight's plots as PNG bytes for the HTML report, or why there are none.

The figures are :mod:`mkflight.analysis.plots`' own (the ones ``mkflight plot`` writes),
drawn into memory instead of files. matplotlib (the ``report`` or ``plot`` extra) is
imported inside :func:`plot_images` only, so the report's module and the CLI's parser
stay light; without it the report says so and keeps its other sections.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

from mkflight.errors import MkflightError
from mkflight.logs import table3, table4
from mkflight.logs.flight import FlightData

INSTALL_HINT = "pip install 'mkflight[report]'"


@dataclass(frozen=True, slots=True)
class PlotImages:
    """Each figure's name and PNG bytes, in the order drawn; ``missing``: why none, or ""."""

    images: tuple[tuple[str, bytes], ...]
    missing: str = ""


def _without_rows(flight: FlightData) -> list[str]:
    """The tables the plots need that the folder lacks (or holds no row of)."""
    return [
        name
        for name, rows in ((table4.FILE_NAME, flight.imu), (table3.FILE_NAME, flight.laser))
        if len(rows) == 0
    ]


def plot_images(flight: FlightData, dpi: int = 100) -> PlotImages:
    """The plots of ``flight`` as PNG bytes; none, with the reason, if they cannot be drawn.

    They need matplotlib and both tables with rows (as ``mkflight plot``).
    """
    lacking = _without_rows(flight)
    if lacking:
        return PlotImages((), f"no plots: {' and '.join(lacking)} missing or without rows")
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return PlotImages((), f"no plots: matplotlib is not installed ({INSTALL_HINT})")
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from mkflight.analysis.plots import flight_figures

    try:
        figures = flight_figures(flight)
    except (MkflightError, ValueError, IndexError) as err:  # a folder the plots do not fit
        return PlotImages((), f"no plots: {err}")
    images: list[tuple[str, bytes]] = []
    for name, fig in figures:
        FigureCanvasAgg(fig)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
        images.append((name, buf.getvalue()))
    return PlotImages(tuple(images))
