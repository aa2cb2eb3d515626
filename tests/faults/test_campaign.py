"""The fault campaign (issues 10, 18): every fault of :mod:`tests.faults.scenarios`, judged
alike by :mod:`tests.faults.judge`.

The flights are real (simulator and daemon in their own processes, on ptys, in real time)
and fly in the background while the suite's other tests run (:mod:`tests.background`; a
test flies only the scenarios it reads); CI flies every scenario, and
``tools/faults.py`` runs this module and writes the README's table from the verdicts
(``MKFLIGHT_FAULTS_REPORT``). Faults that need no flight (NaN, inf and huge values in the
config and in a recorded flight to replay) are judged here too.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import re
import shutil
import subprocess
from collections.abc import Mapping
from pathlib import Path

import pytest

from mkflight.logs import load_flight
from tests.background import Background, job
from tests.faults.campaign import PY, REPO, Flight, fly
from tests.faults.judge import Verdict, judge, report_row
from tests.faults.scenarios import SCENARIOS
from tests.limits_check import flown_config, limit_violations

for _sc in SCENARIOS:
    job(f"campaign/{_sc.name}")(functools.partial(fly, _sc))


def _reads(*names: str) -> pytest.MarkDecorator:
    """The marker of a test that reads the flights of the scenarios ``names``."""
    return pytest.mark.background(*(f"campaign/{name}" for name in names))


@pytest.fixture(scope="module")
def flights(background: Background) -> Mapping[str, Flight]:
    """Each scenario's flight, by name (waited for when a test first reads it)."""
    return background.results({sc.name: f"campaign/{sc.name}" for sc in SCENARIOS})


@pytest.mark.parametrize("name", [pytest.param(sc.name, marks=_reads(sc.name)) for sc in SCENARIOS])
def test_fault(name: str, flights: Mapping[str, Flight]) -> None:
    flight = flights[name]
    if flight.skipped is not None:
        pytest.skip(flight.skipped)
    verdict = judge(flight)
    report_row(verdict)
    known = flight.scenario.known_issue
    if verdict.problems and known is not None:
        pytest.xfail(f"known daemon issue: {known}: {verdict.problems}")
    tail = "\n".join(flight.stderr.splitlines()[-8:])
    assert not verdict.problems, f"{verdict.problems}\nstderr tail:\n{tail}"


@pytest.mark.parametrize(
    "hover", [pytest.param(h, marks=_reads(h)) for h in ("baseline", "sigterm")]
)
def test_a_plain_hover_passes_no_fault_row(hover: str, flights: Mapping[str, Flight]) -> None:
    """Issue 18: a row must prove its fault. A plain hover, ended by ``--duration`` or by
    SIGTERM, judged as any other scenario's flight fails that row (its fault never fired,
    the daemon recorded nothing of it, or the outcome is a hover's)."""
    flight = flights[hover]
    if flight.skipped is not None:
        pytest.skip(flight.skipped)
    passed = [
        sc.name
        for sc in SCENARIOS
        if sc.name != hover and not judge(dataclasses.replace(flight, scenario=sc)).problems
    ]
    assert passed == [], f"rows a plain {hover} flight passes: {passed}"


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [PY, "-m", "mkflight", *args],
        capture_output=True,
        text=True,
        cwd=REPO,
        stdin=subprocess.DEVNULL,
        timeout=120,
        check=False,
    )


def _value_row(
    name: str, what: str, proc: subprocess.CompletedProcess[str], problems: list[str]
) -> Verdict:
    error = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
    if "Traceback" in proc.stderr or "internal error" in proc.stderr:
        problems.append("a traceback or an internal error")
    return Verdict(
        name=name,
        what=what,
        end="ground",
        code=proc.returncode,
        message=error[-1].removeprefix("error:").strip() if error else "",
        commands=0,
        max_tilt_counts=0.0,
        max_gas=0,
        config0_sent=False,
        released_by="",
        logs="none",
        problems=problems,
    )


BAD_VALUES = ["nan", "inf", "-inf", ".nan", "1e400", "1e300", "'12'", "[1, 2]", "{a: 1}"]


@pytest.mark.parametrize("value", BAD_VALUES)
def test_bad_values_in_the_config_never_fly(value: str, tmp_path: Path) -> None:
    """``--set`` and a config file: exit 2, one line naming the key, no folder, no flight."""
    folder = tmp_path / "flight"
    config = tmp_path / "bad.yaml"
    config.write_text(f"control:\n  kp_xy: {value}\n", encoding="utf-8")
    for how, args in (
        ("--set", ["--set", f"control.kp_xy={value}"]),
        ("config file", ["--config", str(config)]),
    ):
        proc = _cli("fly", "--hover", "--sim", "--log-dir", str(folder), *args)
        problems: list[str] = []
        if proc.returncode != 2:
            problems.append(f"exit {proc.returncode}, expected 2")
        if "control.kp_xy" not in proc.stderr:
            problems.append("the message does not name control.kp_xy")
        if folder.exists():
            problems.append("a flight folder was created")
        verdict = _value_row(f"config-{how}-{value}", f"kp_xy = {value} ({how})", proc, problems)
        if value == "nan" and how == "--set":
            report_row(verdict)
        assert not problems, (how, proc.stderr)


def _tamper_poses(folder: Path, token: str) -> int:
    """Put ``token`` in place of x_m in every second scan event after take-off."""
    path = folder / "events.jsonl"
    lines = path.read_text(encoding="utf-8").splitlines()
    changed = 0
    for i, line in enumerate(lines):
        if '"event":"scan"' in line.replace(" ", "") and i > len(lines) // 3 and i % 2:
            new = re.sub(r'"x_m":\s*-?[0-9.e+-]+', f'"x_m":{token}', line)
            changed += new != line
            lines[i] = new
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return changed


@_reads("baseline")
@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity", "1e400", "1e300", "null"])
def test_bad_values_in_a_recorded_flight(
    token: str, flights: Mapping[str, Flight], tmp_path: Path
) -> None:
    """Poses in events.jsonl replaced by NaN, inf, huge, null: the replay either refuses the
    file in one line or flies it; then every command stays in limits and the determinism
    check reports the difference (exit 1). Never a traceback, never a hang."""
    source = tmp_path / "flight"
    shutil.copytree(flights["baseline"].folder, source)
    assert _tamper_poses(source, token) > 10
    out = tmp_path / "replayed"
    proc = _cli("replay", str(source), "--out", str(out))
    problems: list[str] = []
    if proc.returncode != 1:
        problems.append(f"exit {proc.returncode}, expected 1")
    if out.exists():
        data = load_flight(out)
        cmds = data.commands
        counts = zip(cmds["nick"], cmds["roll"], cmds["yaw"], cmds["gas"], strict=True)
        if len(cmds) == 0:
            problems.append("the replay wrote no command")
        elif bad := limit_violations(counts, flown_config(out)):
            problems.append(f"{len(bad)} replayed commands out of limits, e.g. {bad[0]}")
        elif int(cmds["config"][-1]) != 0:
            problems.append("the replay did not end with Config = 0")
        summary = json.loads((out / "flight.json").read_text(encoding="utf-8")).get("summary")
        if not summary:
            problems.append("the replay's flight.json has no summary")
    elif not proc.stderr.strip().startswith("error:"):
        problems.append("neither a replay nor an error line")
    verdict = _value_row(
        f"replay-{token}", f"pose x = {token} in a recording, replayed", proc, problems
    )
    if token in ("NaN", "1e400"):
        report_row(verdict)
    assert not problems, proc.stderr[-2000:]
