"""The determinism check's comparison of two ExternControl streams."""

from __future__ import annotations

from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from mkflight.mk.messages import ExternControl
from mkflight.replay.compare import compare_commands
from mkflight.replay.report import TABLES, compare_tables, last_rows

command = st.builds(
    ExternControl,
    nick=st.integers(-127, 127),
    roll=st.integers(-127, 127),
    yaw=st.integers(-127, 127),
    gas=st.integers(0, 255),
    config=st.integers(0, 1),
)


def _stream(cmds: list[ExternControl]) -> list[tuple[int, bytes]]:
    return [(1_000_000 * (i + 1), c.encode()) for i, c in enumerate(cmds)]


@given(st.lists(command, max_size=40))
def test_a_stream_equals_itself(cmds: list[ExternControl]) -> None:
    s = _stream(cmds)
    c = compare_commands(s, list(s))
    assert c.identical
    assert c.n_identical == len(cmds)
    assert all(ch.frames_differing == 0 for ch in c.channels)


@given(st.lists(command, min_size=1, max_size=40), st.data())
def test_the_first_changed_frame_is_found_with_both_frames(
    cmds: list[ExternControl], data: st.DataObject
) -> None:
    i = data.draw(st.integers(0, len(cmds) - 1))
    old = cmds[i]
    new = ExternControl(
        nick=old.nick, roll=old.roll, yaw=old.yaw, gas=(old.gas + 7) % 256, config=old.config
    )
    changed = [*cmds[:i], new, *cmds[i + 1 :]]
    a, b = _stream(cmds), _stream(changed)
    c = compare_commands(a, b)
    assert not c.identical
    assert c.first is not None
    assert c.first.index == i
    assert c.first.original == a[i][1]
    assert c.first.replayed == b[i][1]
    assert c.first.t_original_ns == a[i][0]
    gas = next(ch for ch in c.channels if ch.name == "gas")
    assert gas.frames_differing == 1
    assert gas.max_abs == abs(new.gas - old.gas)
    assert c.n_identical == len(cmds) - 1


def test_a_missing_tail_is_a_difference_at_the_first_missing_frame() -> None:
    cmds = [ExternControl(nick=k, roll=0, yaw=0, gas=100, config=1) for k in range(5)]
    a = _stream(cmds)
    c = compare_commands(a, a[:3])
    assert not c.identical
    assert c.first is not None
    assert (c.first.index, c.first.replayed, c.first.original) == (3, None, a[3][1])
    assert c.n_identical == 3


def _tables(folder: Path, rows: dict[str, int], changed: int | None = None) -> Path:
    folder.mkdir()
    for name, n in rows.items():
        lines = ["a b index"] + [
            f"{0.5 if i == changed else 0.25} {i * 2} {i}" for i in range(1, n + 1)
        ]
        (folder / name).write_text("\n".join(lines) + "\n")
    return folder


def test_a_killed_flights_tables_are_compared_up_to_their_last_recorded_row(
    tmp_path: Path,
) -> None:
    """The replayed daemon may step once more on a DebugOut the killed process had read
    but not yet written a row for: that row is not held against it; a row before is."""
    original = _tables(tmp_path / "o", {TABLES[0]: 112, TABLES[1]: 60})
    replayed = _tables(tmp_path / "r", {TABLES[0]: 113, TABLES[1]: 60})
    assert last_rows(original) == {TABLES[0]: 112, TABLES[1]: 60}
    assert not all(t.equal for t in compare_tables(original, replayed))
    assert all(t.equal for t in compare_tables(original, replayed, upto=last_rows(original)))
    changed = _tables(tmp_path / "c", {TABLES[0]: 113, TABLES[1]: 60}, changed=112)
    table4 = compare_tables(original, changed, upto=last_rows(original))[0]
    assert not table4.equal
    assert table4.first_difference == 113  # the header is line 1
