"""``mkflight plot``: PNG figures of a fresh simulated flight, and its error paths.

matplotlib comes with the ``test`` extra, so these tests need it rather than skip without it
(the command's own error then names the ``plot`` extra); the one test that removes it from
``sys.modules`` checks that message.
"""

from __future__ import annotations

import shutil
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import structlog

from mkflight.analysis.plots import PlotError
from mkflight.cli import main
from mkflight.commands.plot import cmd_plot
from mkflight.config import Config
from mkflight.errors import ReplayError
from mkflight.sim.hover import run_hover

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
FIGURES = ("trajectory", "position", "velocity", "commands", "battery")


@pytest.fixture(autouse=True)
def _restore_events() -> Iterator[None]:
    """``main()`` points structlog at the (captured) stderr: put the old setup back."""
    saved = structlog.get_config()
    yield
    structlog.configure(**saved)


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One 12 s simulated hover folder, shared read-only by the tests (copy to modify)."""
    folder = tmp_path_factory.mktemp("plot") / "flight"
    run_hover(Config(), duration_s=12, seed=1, log_dir=folder)
    return folder


def _copy(flight: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "flight"
    shutil.copytree(flight, dst)
    return dst


def _assert_pngs(paths: list[Path]) -> None:
    for path in paths:
        data = path.read_bytes()
        assert data.startswith(PNG_SIGNATURE), path
        assert len(data) > 5_000, f"{path}: only {len(data)} bytes"


def test_plot_writes_every_figure_as_png(
    flight: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "figs"
    assert cmd_plot(log_dir=str(flight), out_dir=str(out)) == 0
    printed = [Path(line) for line in capsys.readouterr().out.splitlines()]
    assert printed == [out / f"{name}.png" for name in FIGURES]
    assert sorted(out.iterdir()) == sorted(printed)
    _assert_pngs(printed)


def test_plot_defaults_to_logdir_plots_through_the_cli(
    flight: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _copy(flight, tmp_path)
    assert main(["plot", str(folder)]) == 0
    pngs = sorted((folder / "plots").glob("*.png"))
    assert len(pngs) == len(FIGURES)
    assert len(capsys.readouterr().out.splitlines()) == len(FIGURES)
    _assert_pngs(pngs)


def test_plot_of_the_two_tables_alone(flight: Path, tmp_path: Path) -> None:
    """The seed's own logs (TABLE III and IV only): four figures, no battery."""
    folder = tmp_path / "tables"
    folder.mkdir()
    for name in ("laser_100ms.log", "imu_50ms.log"):
        shutil.copy(flight / name, folder / name)
    assert cmd_plot(log_dir=str(folder), out_dir=None) == 0
    pngs = sorted((folder / "plots").glob("*.png"))
    assert [p.stem for p in pngs] == sorted(FIGURES[:4])
    _assert_pngs(pngs)


def test_missing_matplotlib_names_the_extra(
    flight: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # `import matplotlib` now fails
    with pytest.raises(PlotError, match=r"matplotlib.*pip install 'mkflight\[plot\]'"):
        cmd_plot(log_dir=str(flight), out_dir=str(tmp_path / "figs"))
    assert main(["plot", str(flight), "-o", str(tmp_path / "figs")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ")
    assert "pip install 'mkflight[plot]'" in err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "figs").exists()


def test_missing_folder_is_a_clear_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["plot", str(tmp_path / "nope")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ")
    assert "not a flight folder" in err


def test_missing_table_names_the_file(flight: Path, tmp_path: Path) -> None:
    folder = _copy(flight, tmp_path)
    (folder / "imu_50ms.log").unlink()
    with pytest.raises(ReplayError, match=r"imu_50ms\.log: cannot read"):
        cmd_plot(log_dir=str(folder), out_dir=None)


def test_empty_log_is_a_clear_error(
    flight: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _copy(flight, tmp_path)
    log = folder / "laser_100ms.log"
    log.write_text(log.read_text().splitlines()[0] + "\n")  # the header, no rows
    with pytest.raises(PlotError, match=r"laser_100ms\.log: the log has no rows"):
        cmd_plot(log_dir=str(folder), out_dir=None)
    log.write_text("")  # not even a header
    assert main(["plot", str(folder)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ")
    assert "laser_100ms.log:1: expected the header" in err
    assert not (folder / "plots").exists()


def test_malformed_row_names_file_and_line(flight: Path, tmp_path: Path) -> None:
    folder = _copy(flight, tmp_path)
    log = folder / "imu_50ms.log"
    lines = log.read_text().splitlines(keepends=True)
    lines[3] = "1 2 3\n"
    log.write_text("".join(lines))
    with pytest.raises(ReplayError, match=r"imu_50ms\.log:4: expected 14 columns"):
        cmd_plot(log_dir=str(folder), out_dir=None)


def test_malformed_truth_log_is_a_clear_error(flight: Path, tmp_path: Path) -> None:
    folder = _copy(flight, tmp_path)
    (folder / "truth.txt").write_text("t x y z\n0.1 0.2\n")
    with pytest.raises(ReplayError, match=r"truth\.txt:2: expected 't x y z'"):
        cmd_plot(log_dir=str(folder), out_dir=None)
