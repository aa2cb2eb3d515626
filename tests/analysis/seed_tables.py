"""The seed's TABLE I and II (§D), transcribed exactly: three measurement rows per table.

Each table's columns are the true angles; each row is one measurement run of raw MK counts
(AccNick for TABLE I, AccRoll for TABLE II). The seed's printed "Mean" rows are kept apart:
they are truncated to one decimal, not rounded (e.g. TABLE I at 50°: the runs' mean is
-460.67 but the seed prints -460.6), so they are not data.
"""

from __future__ import annotations

ANGLES_DEG = (-90, -60, -50, -45, -15, 0, 15, 45, 50, 60, 90)

TABLE_I_RUNS = (
    (602, 522, 458, 428, 152, 0, -122, -431, -457, -531, -617),
    (602, 525, 468, 432, 154, 0, -123, -433, -462, -532, -618),
    (602, 523, 470, 422, 153, 0, -122, -432, -463, -532, -617),
)
TABLE_I_MEAN = (602, 523.3, 465.3, 427.3, 153, 0, -122.3, -432, -460.6, -531.6, -617.3)

TABLE_II_RUNS = (
    (612, 522, 458, 436, 162, 0, -167, -430, -462, -522, -587),
    (611, 521, 456, 443, 161, 0, -162, -432, -463, -515, -588),
    (613, 523, 457, 439, 160, 0, -165, -431, -463, -517, -588),
)
TABLE_II_MEAN = (612, 522, 457, 439.3, 161, 0, -164.6, -431, -462.6, -518, -587.6)


def as_text(runs: tuple[tuple[float, ...], ...], *, sep: str = " ", header: bool = True) -> str:
    """The table as the input format of ``calibrate acc``: one 'angle_deg counts' row a line."""
    lines = [f"angle_deg{sep}counts"] if header else []
    for run in runs:
        lines.extend(f"{a}{sep}{c}" for a, c in zip(ANGLES_DEG, run, strict=True))
    return "\n".join(lines) + "\n"
