"""tools/soak.py on a short flight: the report's plumbing, not the machine's timing.

One real-time flight of 0.4 min (the daemon in the tool's process, the simulator in its
child, on ptys) as a subprocess, flown in the background (:mod:`tests.background`); the
assertions are about the report being complete and self-consistent. Missed steps are not
asserted absent: under a loaded CI machine a late DebugOut is the machine's, and the tool's
exit code then says 1 by design.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.background import Background, job

pytestmark = pytest.mark.background("soak")

SOAK = Path(__file__).resolve().parents[2] / "tools" / "soak.py"
MINUTES = 0.4


@job("soak")
def _soak(base: Path) -> tuple[int, str, dict[str, Any]]:
    out = base / "soak.json"
    proc = subprocess.run(
        # The worker process (not the default inline matcher): its memory is reported too.
        [
            *(sys.executable, str(SOAK), "--minutes", str(MINUTES), "--json", str(out)),
            *("--set", "scanmatch.worker=process"),
        ],
        capture_output=True,
        text=True,
        check=False,
        stdin=subprocess.DEVNULL,
        timeout=600,  # a hung run fails instead of blocking the suite; not a figure
    )
    assert proc.returncode in (0, 1), proc.stderr[-2000:]
    return proc.returncode, proc.stdout, json.loads(out.read_text())


@pytest.fixture(scope="module")
def soak(background: Background) -> tuple[int, str, dict[str, Any]]:
    result: tuple[int, str, dict[str, Any]] = background.result("soak")
    return result


def test_the_flight_holds_for_the_duration_and_lands_with_exit_0(
    soak: tuple[int, str, dict[str, Any]],
) -> None:
    _, _, r = soak
    fl = r["flight"]
    assert fl["exit_code"] == 0, fl["reason"]
    assert fl["final_phase"] == "RELEASED"
    assert fl["reason"].startswith("--duration")
    assert r["hold"]["hold_s"] > 0
    assert not r["hold"]["left_hold_before_stop"]
    assert r["verdict"]["abnormal"] == []


def test_step_counts_are_consistent(soak: tuple[int, str, dict[str, Any]]) -> None:
    code, _out, r = soak
    st = r["steps"]
    # every DebugOut the link received was stepped or counted as dropped; one command a step
    assert st["debugouts_received"] == st["steps"] + st["samples_dropped"]
    assert st["externcontrols_sent"] == st["steps"]
    # ~19 steps a second (the FC's ~53 ms period): loose, and from the flight's own clock
    expected = st["flight_s"] * 1000.0 / st["period_median_ms"]
    assert abs(st["steps"] - expected) <= 0.1 * expected + st["gaps"] + st["samples_dropped"]
    assert 10 < st["steps_per_s"] < 30
    assert st["steps"] >= MINUTES * 60 * 10
    # the verdict follows the counts
    assert (code == 0) == r["verdict"]["ok"]
    assert r["verdict"]["missed_total"] == sum(max(0, v) for v in r["verdict"]["missed"].values())
    assert sum(c["gaps"] for c in st["by_cause"].values()) == st["gaps"]
    # the emulators' late wake-ups come back from the simulator's process, both of them
    late = r["simulator_late"]
    assert set(late) == {"fc", "urg"}
    assert all(v["count"] >= len(v["at_s"]) for v in late.values())
    assert "simulator woke late to send: FC " in _out


def test_windows_cover_every_step_with_their_figures(soak: tuple[int, str, dict[str, Any]]) -> None:
    _, out, r = soak
    windows = r["windows"]
    assert len(windows) == 5  # four quarters of the hover, then the landing
    assert windows[-1]["label"] == "landing"
    assert sum(w["steps"] for w in windows) == r["steps"]["steps"]
    for w in windows:
        assert w["steps"] > 0
        lat = w["latency_ms"]
        assert 0 <= lat["p50"] <= lat["p99"] <= lat["max"]
        dev = w["period_dev_ms"]
        assert 0 <= dev["p50"] <= dev["p99"] <= dev["max"]
        assert w["cpu_ms_per_step"] > 0
        assert w["battery_v"] > 0
    for w in windows[:4]:
        assert w["traced_b"] > 0
        assert w["rss_b"] > 0
        assert w["wind_std_mps"] > 0
    for label in ("lat p50", "traced MB", "verdict:", "top 5 growing"):
        assert label in out


def test_memory_figures_are_numbers(soak: tuple[int, str, dict[str, Any]]) -> None:
    _, _, r = soak
    mem = r["memory"]
    assert mem["tracing"]
    assert mem["first_traced_b"] > 0
    assert mem["last_traced_b"] > 0
    assert isinstance(mem["traced_growth_per_10min_b"], float)
    kinds = [s["kind"] for s in mem["samples"]]
    assert kinds[0] == "start"
    assert kinds[-1] == "end"
    assert kinds.count("sample") == 8  # every eighth of a short flight
    assert all(s["traced_b"] > 0 and s["rss_b"] > 0 for s in mem["samples"])
    assert len(mem["snapshots"]) == 2  # after two samples, and at the last step
    assert all(s["took_ms"] > 0 for s in mem["snapshots"])
    for site in mem["top_growth"]:
        assert ":" in site["site"]
        assert site["size_diff_b"] > 0
    procs = r["processes"]
    assert procs["matcher"]["pid"] is not None
    assert procs["matcher"]["rss_start_b"] > 0
    assert procs["matcher"]["rss_end_b"] > 0
    assert any(c["pid"] == procs["matcher"]["pid"] for c in procs["children_at_start"])


def test_battery_drains_and_gusts_blow(soak: tuple[int, str, dict[str, Any]]) -> None:
    _, _, r = soak
    bat = r["battery"]
    assert bat["truth_v_end"] < bat["truth_v_start"]  # the simulator's pack, without noise
    assert bat["used_ah_end"] > 0
    assert r["plan"]["capacity_ah"] == 2.2  # the default pack suffices for 0.4 min
    assert all(v > 0 for v in r["gusts"]["wind_std_mps"])
