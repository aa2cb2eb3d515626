"""``mkflight report``: the HTML page of a real simulated flight, opened in headless Chromium.

One flight (``fly --hover --sim``) is recorded for the module; the page is checked against
that folder's own figures (``flight.json``, ``events.jsonl``, ``analyze precision``), in the
text Chromium renders and in its screenshot. Damaged copies (the two tables alone, a
killed flight, no truth) must still give a page that says what is missing.

Chromium (Debian's ``chromium``) is installed by ``.ci/run``: without it these tests skip
with the reason on a workstation, and fail under CI (``$CI`` set).
"""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.background import Background
from tests.flights import HOVER_SIM_8S

pytestmark = pytest.mark.background(HOVER_SIM_8S)

ROOT = Path(__file__).resolve().parents[2]
BROWSER_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
HOLD_GREEN = (0x74, 0xC4, 0x76)  # the timeline's HOLD colour (report_timeline.PHASE_COLOURS)


def _mkflight(*args: str, timeout: float = 180.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mkflight", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
        check=False,
    )


@pytest.fixture(scope="module")
def flight(background: Background) -> Path:
    """One real simulated flight (the daemon on the simulator's ptys), read-only."""
    folder: Path = background.result(HOVER_SIM_8S)
    return folder


@pytest.fixture(scope="module")
def page(flight: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The flight's report, written beside a copy of the folder (the default name)."""
    folder = tmp_path_factory.mktemp("page") / "flight"
    shutil.copytree(flight, folder)
    done = _mkflight("report", str(folder))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == str(folder / "report.html")
    return folder / "report.html"


class _Sections(HTMLParser):
    """The visible text of each ``<section id=...>`` (style and attributes left out)."""

    def __init__(self) -> None:
        super().__init__()
        self.text: dict[str, list[str]] = {"": []}
        self.current = ""
        self.in_style = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "section":
            self.current = dict(attrs).get("id") or ""
            self.text.setdefault(self.current, [])
        self.in_style = tag == "style"

    def handle_endtag(self, tag: str) -> None:
        if tag == "section":
            self.current = ""
        if tag == "style":
            self.in_style = False

    def handle_data(self, data: str) -> None:
        if not self.in_style:
            self.text[self.current].append(data)


def sections(html: str) -> dict[str, str]:
    """Section id -> its text, words joined by single spaces ("" : outside any section)."""
    parser = _Sections()
    parser.feed(html)
    return {k: " ".join(" ".join(v).split()) for k, v in parser.text.items()}


def _report(folder: Path, tmp_path: Path) -> tuple[str, dict[str, str]]:
    out = tmp_path / "out.html"
    done = _mkflight("report", str(folder), "-o", str(out))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == str(out)
    html = out.read_text(encoding="utf-8")
    _assert_offline(html)
    return html, sections(html)


def _assert_offline(html: str) -> None:
    """Nothing is fetched: no script, stylesheet link, remote src/href, url() or @import."""
    assert "<script" not in html.lower()
    assert "<link" not in html.lower()
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", html, re.IGNORECASE)
    assert "http://" not in html
    assert "https://" not in html
    assert "url(" not in html
    assert "@import" not in html


def _summary(folder: Path) -> dict[str, Any]:
    summary: dict[str, Any] = json.loads((folder / "flight.json").read_text())["summary"]
    return summary


def _precision(folder: Path, *truth: str) -> dict[str, Any]:
    done = _mkflight("analyze", "precision", str(folder), "--json", *truth)
    assert done.returncode == 0, done.stderr
    result: dict[str, Any] = json.loads(done.stdout)
    return result


def _assert_row(text: str, label: str, values: list[float], samples: int | None = None) -> None:
    """``text`` shows ``label`` followed by ``values`` to 4 decimals (and ``samples``).

    The values come from ``analyze precision --json``, which rounds to 6 decimals, and the
    page rounds the unrounded figure to 4: a value on a rounding boundary may show one unit
    of the last place apart (0.0219498 -> "0.0219", but 0.02195 -> "0.0220").
    """
    number = r"(-?\d+\.\d{4})"
    pattern = re.escape(label) + " " + " ".join([number] * len(values))
    if samples is not None:
        pattern += f" {samples}\\b"
    found = re.search(pattern, text)
    assert found is not None, f"no {label!r} row in {text!r}"
    shown = [float(g) for g in found.groups()]
    assert all(abs(a - b) <= 0.5e-4 + 1e-6 for a, b in zip(shown, values, strict=True)), (
        shown,
        values,
    )


def _chromium() -> str:
    path = shutil.which("chromium")
    if path is None:
        reason = "chromium is not installed (.ci/run installs it: apt-get install chromium)"
        if os.environ.get("CI"):
            pytest.fail(f"{reason}; CI must have it")
        pytest.skip(reason)
    return path


def _browser(page: Path, tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(
        [_chromium(), *BROWSER_FLAGS, f"--user-data-dir={tmp_path / 'profile'}", *args],
        input=None,
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
        stdin=subprocess.DEVNULL,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done


def test_chromium_renders_the_flight_s_own_figures(
    page: Path, flight: Path, tmp_path: Path
) -> None:
    dom = _browser(page, tmp_path, "--dump-dom", page.as_uri()).stdout
    text = sections(dom)
    s = _summary(flight)
    info = json.loads((flight / "flight.json").read_text())
    for key in ("start_utc", "mkflight_version", "fc_version"):
        assert info[key] in text["summary"], key
    assert info["config_source"]["file"] is None  # the fixture flies the built-in defaults
    assert "config source built-in defaults" in " ".join(text["summary"].split())
    events = [json.loads(line) for line in (flight / "events.jsonl").read_text().splitlines()]
    checked = next(e for e in events if e["event"] == "preflight")
    assert f"pre-flight check {checked['battery_v']:.2f} V" in text["summary"]
    volts = [e["battery_v"] for e in events if e["event"] == "step" and e["battery_v"]]
    assert f"{volts[0]:.2f} / {volts[-1]:.2f} / {min(volts):.2f} V" in text["summary"]
    assert s["end_reason"] in text["summary"]
    assert f"{s['duration_s']:.1f} s" in text["summary"]
    assert f"{s['flight_s']:.1f} s" in text["summary"]
    t = s["timing"]
    for key in ("latency_median_ms", "latency_p99_ms", "added_jitter_p99_ms"):
        assert f"{t[key]:.2f} ms" in text["timing"], key
    assert f"missed steps {t['missed_steps']}" in text["timing"]
    assert f"{s['cpu_percent_of_one_core']:.2f} % of one core" in text["timing"]
    assert f"crc_errors {s['mk_link']['crc_errors']}" in text["counters"]
    assert f"parser_bytes_in {s['laser_link']['parser_bytes_in']}" in text["counters"]
    assert f"records {s['mk_raw']['records']}" in text["counters"]
    for source, p in (
        ("truth", _precision(flight, "--truth", str(flight / "truth.txt"))),
        ("estimate", _precision(flight)),
    ):
        for stat, name in (("std", "std"), ("rms", "RMS")):
            values = [p[f"{stat}_{a}_m"] for a in "xyz"]
            _assert_row(text["precision"], f"this flight, {source} {name}", values, p["samples"])
    assert "QUT 2011 std 0.075368 0.080849 0.031913" in text["precision"]
    assert "MIT (RANGE) 2010 RMS 0.06 0.06 0.02" in text["precision"]
    assert "phase HOLD: take-off height reached" in text["timeline"]
    assert "failsafe LAND: stop_duration" in text["timeline"]


def test_chromium_s_screenshot_is_not_blank_and_shows_the_timeline(
    page: Path, tmp_path: Path
) -> None:
    import matplotlib.image as mpimg

    shot = tmp_path / "shot.png"
    _browser(page, tmp_path, f"--screenshot={shot}", "--window-size=1200,3000", page.as_uri())
    pixels = mpimg.imread(shot)[..., :3]
    assert pixels.shape[:2] == (3000, 1200)
    assert float(pixels.std()) > 0.1
    rgb = (pixels * 255).round().astype(np.int64).reshape(-1, 3)
    colours = np.unique(rgb[:, 0] * 65536 + rgb[:, 1] * 256 + rgb[:, 2])
    assert len(colours) > 200
    hold = np.all(np.abs(rgb - np.array(HOLD_GREEN)) <= 3, axis=1).sum()
    assert hold > 5_000  # the HOLD band of the SVG timeline was drawn


def test_every_plot_is_inline_as_a_png(page: Path) -> None:
    import io

    import matplotlib.image as mpimg

    html = page.read_text(encoding="utf-8")
    _assert_offline(html)
    names = re.findall(r'<img alt="(\w+)" src="data:image/png;base64,', html)
    assert names == ["trajectory", "position", "velocity", "commands", "battery"]
    for blob in re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html):
        png = base64.b64decode(blob, validate=True)
        assert png.startswith(PNG_SIGNATURE)
        assert mpimg.imread(io.BytesIO(png)).shape[1] >= 600


def test_the_two_tables_alone_give_a_page_that_says_what_is_missing(
    flight: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "tables"
    folder.mkdir()
    for name in ("imu_50ms.log", "laser_100ms.log"):
        shutil.copy(flight / name, folder / name)
    html, text = _report(folder, tmp_path)
    assert "no flight.json: the folder holds the original system's tables only" in text["summary"]
    assert "no timeline: the folder has no events.jsonl" in text["timeline"]
    assert "no hover precision" in text["precision"]
    assert "no truth.txt" not in html  # nothing to measure, with or without a truth
    assert "QUT 2011 std 0.075368" in text["precision"]  # TABLE IX is there all the same
    rows = len((flight / "imu_50ms.log").read_text().splitlines()) - 1
    assert f"TABLE IV rows (imu_50ms.log) {rows}" in text["counters"]
    assert re.findall(r'<img alt="(\w+)"', html) == [
        "trajectory",
        "position",
        "velocity",
        "commands",
    ]
    assert "What this folder lacks:" in text[""]


def test_a_killed_flight_without_summary_shows_the_step_events_timing(
    flight: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "killed"
    shutil.copytree(flight, folder)
    info = json.loads((folder / "flight.json").read_text())
    info["summary"] = None
    (folder / "flight.json").write_text(json.dumps(info))
    lines = (folder / "events.jsonl").read_text().splitlines()
    cut = next(i for i, line in enumerate(lines) if '"event":"stop"' in line)
    (folder / "events.jsonl").write_text("\n".join(lines[:cut]) + "\n" + lines[cut][:25])
    _, text = _report(folder, tmp_path)
    assert "flight.json has no summary: the flight did not end" in text["summary"]
    checked = json.loads(next(line for line in lines if '"event":"preflight"' in line))
    assert f"pre-flight check {checked['battery_v']:.2f} V" in text["summary"]
    latency = [
        e["latency_ms"]
        for e in map(json.loads, lines[:cut])
        if e["event"] == "step" and e.get("latency_ms") is not None
    ]
    assert f"command latency median {np.median(latency):.2f} ms" in text["timing"]
    assert f"command latency p99 {np.percentile(latency, 99):.2f} ms" in text["timing"]
    assert "no link counters" in text["counters"]
    assert "incomplete last event dropped" in text[""]  # the reader's warning, at the top
    assert "this flight, truth std" in text["precision"]


def test_a_folder_without_truth_measures_the_estimate_only(flight: Path, tmp_path: Path) -> None:
    folder = tmp_path / "real"
    shutil.copytree(flight, folder)
    (folder / "truth.txt").unlink()
    _, text = _report(folder, tmp_path)
    p = _precision(folder)
    values = [p[f"std_{a}_m"] for a in "xyz"]
    _assert_row(text["precision"], "this flight, estimate std", values)
    assert "this flight, truth" not in text["precision"]
    assert "no truth.txt in the folder" in text["precision"]


def test_a_failsafe_nobody_asked_for_turns_the_verdict_amber_and_its_line_red(
    flight: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "failsafe"
    shutil.copytree(flight, folder)
    info = json.loads((folder / "flight.json").read_text())
    info["summary"]["failsafes"].insert(0, "t+3.00s LAND laser_stale")
    (folder / "flight.json").write_text(json.dumps(info))
    html, _ = _report(folder, tmp_path)
    assert '<span class="verdict warn">' in html
    assert '<td class="alarm">t+3.00s LAND laser_stale; ' in html
    plain, _ = _report(flight, tmp_path)
    assert '<span class="verdict ok">' in plain
    assert 'class="alarm"' not in plain


def test_text_from_the_folder_is_escaped(flight: Path, tmp_path: Path) -> None:
    folder = tmp_path / "hostile"
    shutil.copytree(flight, folder)
    lines = (folder / "events.jsonl").read_text().splitlines()
    t_ns = json.loads(lines[-1])["t_ns"]
    crash = {"t_ns": t_ns, "event": "crash", "task": "<b>x</b>", "error": "<script>alert(1)"}
    lines.insert(-1, json.dumps(crash))
    (folder / "events.jsonl").write_text("\n".join(lines) + "\n")
    html, text = _report(folder, tmp_path)
    assert "&lt;script&gt;alert(1)" in html
    assert "<b>x</b>" not in html
    assert "crash in task <b>x</b>: <script>alert(1)" in text["timeline"]


def test_a_sim_hover_folder_shows_its_own_summary(tmp_path: Path) -> None:
    from mkflight.config import Config
    from mkflight.sim.hover import run_hover

    folder = tmp_path / "hover"
    run_hover(Config(), duration_s=8, seed=1, log_dir=folder)
    summary = _summary(folder)
    _, text = _report(folder, tmp_path)
    assert f"end (sim hover) {summary['end']}" in text["summary"]
    assert f"{summary['sim_s']:.1f} s" in text["summary"]
    assert "this flight, truth std" in text["precision"]


@pytest.mark.parametrize("make", ["missing", "empty"])
def test_not_a_flight_folder_is_one_error_line(make: str, tmp_path: Path) -> None:
    folder = tmp_path / "nothing"
    if make == "empty":
        folder.mkdir()
    done = _mkflight("report", str(folder))
    assert done.returncode == 1
    assert done.stdout == ""
    assert done.stderr.count("\n") == 1
    assert done.stderr.startswith(f"error: {folder}: not a flight folder")


def test_an_unwritable_output_is_one_error_line(flight: Path, tmp_path: Path) -> None:
    out = tmp_path / "no" / "such" / "report.html"
    done = _mkflight("report", str(flight), "-o", str(out))
    assert done.returncode == 1
    assert done.stderr.startswith(f"error: {out}: cannot write the report")
    assert done.stderr.count("\n") == 1
    assert not (flight / "report.html").exists()


def test_an_output_that_is_a_folder_leaves_nothing_behind(flight: Path, tmp_path: Path) -> None:
    out = tmp_path / "folder"
    out.mkdir()
    done = _mkflight("report", str(flight), "-o", str(out))
    assert done.returncode == 1
    assert done.stderr.startswith(f"error: {out}: cannot write the report: Is a directory")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder"]
    assert not any(out.iterdir())


def test_a_folder_it_cannot_write_into_points_to_the_output_option(
    flight: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "flight"
    shutil.copytree(flight, folder)
    (folder / "report.html").mkdir()  # stands in for a folder the service owns
    done = _mkflight("report", str(folder))
    assert done.returncode == 1
    assert done.stderr.rstrip("\n").endswith("(-o FILE writes it elsewhere)")
    assert done.stderr.count("\n") == 1
