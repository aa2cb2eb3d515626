r"""Hokuyo SCIP 2.0: sum character, number encoding and command builders (sans-I/O).

Everything here is pure and synchronous (``protocols/scip2.md``); the reply parser is in
:mod:`mkflight.urg.replies`, the parameters and the conversions to SI in
:mod:`mkflight.urg.units`. A command is ``CMD [fixed-width decimal parameters] [;tag]``
ended by LF (§2.1); a reply is ``echo LF status sum LF [lines, each ending in its sum]
LF`` (§2.2). Numbers are written 6 bits a character from ``'0'`` (§2.4); the sum of a
line is the low 6 bits of its byte sum, also from ``'0'`` (§2.3).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt

from mkflight.errors import CommandRangeError

LF: Final = b"\n"
CHAR_OFFSET: Final = 0x30  # '0': every encoded character is 0x30 + a 6-bit value (§2.4)
BLOCK_CHARS: Final = 64  # scan data are cut into blocks of 64 characters (§2.5)
MAX_STEP: Final = 768  # the largest step a command may name (§3.1)
MAX_TAG_CHARS: Final = 16  # the optional ;string (§2.1)
SCIP2_COMMAND: Final = "SCIP2.0"
TIMESTAMP_MODULUS_MS: Final = 1 << 24  # the sensor's ms timer wraps here (§3.3)

_TAG_RE: Final = re.compile(r"[A-Za-z0-9 ._+@]*")
# Bytes deleted by this table are the valid encoded characters '0'..'o' (§2.4); what is left
# after ``data.translate(None, _ENCODED_CHARS)`` is invalid.
_ENCODED_CHARS: Final = bytes(range(CHAR_OFFSET, CHAR_OFFSET + 64))
# Each byte to its 6-bit digit (§2.4); a byte outside '0'..'o' to 0xFF, which no digit is.
_NOT_A_DIGIT: Final = b"\xff"
_DIGITS: Final = bytes(
    c - CHAR_OFFSET if CHAR_OFFSET <= c < CHAR_OFFSET + 64 else 0xFF for c in range(256)
)
# A 2- or 3-character group's digits, most significant first, weighted by 64**k (§2.4).
_GROUP_WEIGHTS: Final = {
    2: np.array([64, 1], dtype=np.int64),
    3: np.array([4096, 64, 1], dtype=np.int64),
}

IntArray = npt.NDArray[np.int64]

# Status meanings (§4). Command-specific meanings first, then the general table.
_STATUS_BY_COMMAND: Final[dict[tuple[str, str], str]] = {
    ("BM", "01"): "laser malfunction",
    ("BM", "02"): "laser was already on (not an error)",
    ("TM", "01"): "invalid control code",
    ("TM", "02"): "time-adjust mode was already on",
    ("TM", "03"): "time-adjust mode was already off",
    ("TM", "04"): "time-adjust mode is off: no time to report",
    ("SS", "01"): "bit rate not numeric",
    ("SS", "02"): "invalid bit rate",
    (SCIP2_COMMAND, "0"): "switched from SCIP 1.1 to SCIP 2.0",
    (SCIP2_COMMAND, "0E"): "already in SCIP 2.0 (success)",
}
_STATUS: Final[dict[str, str]] = {
    "00": "OK",
    "99": "scan message of an MD/MS stream",
    "01": "start step not numeric",
    "02": "end step not numeric",
    "03": "cluster count not numeric",
    "04": "end step out of range (> 768)",
    "05": "end step < start step",
    "06": "scan interval not numeric",
    "07": "number of scans not numeric",
    "10": "laser is off (send BM first)",
    "0A": "reply could not be created",
    "0B": "buffer full or repeated command",
    "0C": "too few parameters",
    "0D": "extra characters or undefined command",
    "0E": "undefined command or not allowed now",
    "0F": "too few parameters",
    "0G": "string longer than 16 characters",
    "0H": "bad character in the string",
    "0I": "sensor in firmware-update mode",
    "98": "MD/MS resumed after a hardware error",
}


def sum_char(line: bytes | bytearray | memoryview) -> int:
    """The sum character (a byte value) of one reply line: ``(sum & 0x3F) + 0x30`` (§2.3)."""
    return (sum(line) & 0x3F) + CHAR_OFFSET


def encode_value(value: int, chars: int) -> bytes:
    """Encode ``value`` in ``chars`` characters of 6 bits, most significant first (§2.4).

    Raises:
        ValueError: ``value`` is negative or needs more than ``6 * chars`` bits.
    """
    if not 0 <= value < 1 << (6 * chars):
        msg = f"value {value} does not fit {chars} SCIP characters"
        raise ValueError(msg)
    return bytes(CHAR_OFFSET + ((value >> (6 * i)) & 0x3F) for i in reversed(range(chars)))


def decode_value(chars: bytes | bytearray | memoryview) -> int:
    """Decode characters written by :func:`encode_value` (§2.4).

    Raises:
        ValueError: a character lies outside ``'0'..'o'``.
    """
    value = 0
    for c in bytes(chars):
        v = c - CHAR_OFFSET
        if not 0 <= v < 64:
            msg = f"byte 0x{c:02x} is not a SCIP character"
            raise ValueError(msg)
        value = (value << 6) | v
    return value


def encode_values(values: Sequence[int], chars: int) -> bytes:
    """Encode and concatenate scan values (mm), ``chars`` characters each (§2.5).

    Raises:
        ValueError: a value does not fit.
    """
    return b"".join(encode_value(v, chars) for v in values)


def decode_values(data: bytes | bytearray, chars: int) -> list[int] | None:
    """Split joined data blocks into values of ``chars`` characters (§2.5).

    Returns:
        The values, or None if the length is not a multiple of ``chars`` or a character
        is invalid (the parser then drops the reply as malformed).
    """
    data = bytes(data)
    if chars in (2, 3):
        values = decode_array(data, chars)
        return None if values is None else values.tolist()
    if len(data) % chars or data.translate(None, _ENCODED_CHARS):
        return None
    return [decode_value(data[i : i + chars]) for i in range(0, len(data), chars)]


def decode_array(data: bytes, chars: int) -> IntArray | None:
    """The values of joined data blocks, ``chars`` (2 or 3) characters each, as an array (§2.5).

    A scan's 682 values without a Python step per value: one table lookup turns every
    character into its 6-bit digit (and an invalid one into 0xFF), then the digits, viewed
    as rows of ``chars``, are weighted by 4096, 64 and 1 in one matrix-vector product.

    Returns:
        The values (int64, read-only), or None if the length is not a multiple of
        ``chars`` or a character is invalid.
    """
    if len(data) % chars:
        return None
    digits = data.translate(_DIGITS)
    if _NOT_A_DIGIT in digits:
        return None
    rows = np.frombuffer(digits, dtype=np.uint8).reshape(-1, chars)
    # in integers, numpy's own loop: a 682x3 product is too small for BLAS to pay off
    # (float64 through BLAS took ~5 us a scan more here, float32 more still)
    values: IntArray = rows.astype(np.int64) @ _GROUP_WEIGHTS[chars]
    values.flags.writeable = False
    return values


def timestamp_line(ms: int) -> bytes:
    """The 4-character timestamp and its sum, without LF (§3.3, vector SC-C8).

    Raises:
        ValueError: ``ms`` outside the 24-bit timer range.
    """
    chars = encode_value(ms, 4)
    return chars + bytes((sum_char(chars),))


def data_blocks(data: bytes) -> bytes:
    """Cut encoded values into 64-character blocks, each followed by its sum and LF (§2.5)."""
    out = bytearray()
    for i in range(0, len(data), BLOCK_CHARS):
        block = data[i : i + BLOCK_CHARS]
        out += block
        out.append(sum_char(block))
        out += LF
    return bytes(out)


def status_line(status: str) -> bytes:
    """A 2-character status with its sum, without LF (§2.2: ``00`` -> ``00P``)."""
    raw = status.encode("ascii")
    return raw + bytes((sum_char(raw),))


def info_line(key: str, value: str) -> bytes:
    """``KEY:value;S`` without LF; the sum covers ``KEY:value`` (§2.3, vector SC-C7)."""
    body = f"{key}:{value}".encode("ascii")
    return body + b";" + bytes((sum_char(body),))


def status_message(command: str, status: str) -> str:
    """A readable meaning of ``status`` in the reply to ``command`` (§4).

    ``command`` is the 2-letter command (``"GD"``) or ``"SCIP2.0"``; a full echo works too.
    """
    name = SCIP2_COMMAND if command.startswith(SCIP2_COMMAND) else command[:2]
    known = _STATUS_BY_COMMAND.get((name, status)) or _STATUS.get(status)
    if known is not None:
        return known
    if len(status) == 2 and status.isdigit():
        code = int(status)
        if 21 <= code <= 49:
            return "MD/MS stopped because of an error"
        if 50 <= code <= 97:
            return "hardware error"
    if status.startswith("0"):
        return "command rejected"
    return "unknown status"


def is_success(command: str, status: str) -> bool:
    """Whether ``status`` means the command worked (§3-4).

    ``00`` and ``99`` always; the bare ``0`` and ``0E`` for ``SCIP2.0`` (both mean the
    sensor now speaks SCIP 2.0); ``02`` for ``BM`` (the laser was already on).
    """
    if status in ("00", "99"):
        return True
    name = SCIP2_COMMAND if command.startswith(SCIP2_COMMAND) else command[:2]
    if name == SCIP2_COMMAND:
        return status in ("0", "0E")
    return name == "BM" and status == "02"


# ----------------------------------------------------------------- commands (§2.1, §3)
def _with_tag(head: str, tag: str | None) -> bytes:
    """Append the optional ``;tag`` and the LF terminator, validating the tag (§2.1)."""
    if tag is not None:
        if len(tag) > MAX_TAG_CHARS:
            msg = f"tag {tag!r} is longer than {MAX_TAG_CHARS} characters"
            raise CommandRangeError(msg)
        if not _TAG_RE.fullmatch(tag):
            msg = f"tag {tag!r} has a character outside letters, digits, ' ._+@'"
            raise CommandRangeError(msg)
        head += ";" + tag
    return head.encode("ascii") + LF


def _check_int(name: str, value: int, low: int, high: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        msg = f"{name} = {value!r} outside {low}..{high}"
        raise CommandRangeError(msg)


def _scan_head(cmd: str, start_step: int, end_step: int, cluster: int) -> str:
    _check_int("start_step", start_step, 0, MAX_STEP)
    _check_int("end_step", end_step, 0, MAX_STEP)
    _check_int("cluster", cluster, 0, 99)
    if end_step < start_step:
        msg = f"end_step {end_step} < start_step {start_step}"
        raise CommandRangeError(msg)
    return f"{cmd}{start_step:04d}{end_step:04d}{cluster:02d}"


def scip2_command() -> bytes:
    """``SCIP2.0``: switch a SCIP 1.1 sensor to SCIP 2.0 (§3, vectors SC-01/02)."""
    return _with_tag(SCIP2_COMMAND, None)


def simple_command(cmd: str, tag: str | None = None) -> bytes:
    """A parameterless command: ``VV``, ``PP``, ``II``, ``BM``, ``QT``, ``RS`` (§3).

    Raises:
        CommandRangeError: ``cmd`` is not two capital letters, or a bad tag.
    """
    if not re.fullmatch(r"[A-Z]{2}", cmd):
        msg = f"command {cmd!r} is not two capital letters"
        raise CommandRangeError(msg)
    return _with_tag(cmd, tag)


def tm_command(mode: int, tag: str | None = None) -> bytes:
    """``TM0`` enter / ``TM1`` read time / ``TM2`` leave time-adjust mode (§3, §6 step 4)."""
    _check_int("mode", mode, 0, 2)
    return _with_tag(f"TM{mode}", tag)


def gd_command(
    start_step: int, end_step: int, cluster: int = 1, *, chars: int = 3, tag: str | None = None
) -> bytes:
    """``GD`` (3-character values) or ``GS`` (``chars=2``): one scan (§3, §3.1).

    Raises:
        CommandRangeError: a parameter outside its range (0 <= start <= end <= 768,
            cluster 0..99), ``chars`` not 2 or 3, or a bad tag.
    """
    cmd = _command_for_chars("GD", "GS", chars)
    return _with_tag(_scan_head(cmd, start_step, end_step, cluster), tag)


def md_command(
    start_step: int,
    end_step: int,
    cluster: int = 1,
    interval: int = 0,
    count: int = 0,
    *,
    chars: int = 3,
    tag: str | None = None,
) -> bytes:
    """``MD`` (3-character values) or ``MS`` (``chars=2``): a scan stream (§3.1-3.2).

    ``interval`` scans are skipped between sent scans (0 = 10 Hz); ``count`` scans are
    sent, 0 = until ``QT``/``RS``. The tag comes back in every echo: use it to tell
    scans of a replaced stream from the new one.

    Raises:
        CommandRangeError: a parameter outside its range, ``chars`` not 2 or 3, bad tag.
    """
    cmd = _command_for_chars("MD", "MS", chars)
    head = _scan_head(cmd, start_step, end_step, cluster)
    _check_int("interval", interval, 0, 9)
    _check_int("count", count, 0, 99)
    return _with_tag(f"{head}{interval:d}{count:02d}", tag)


def _command_for_chars(three: str, two: str, chars: int) -> str:
    if chars == 3:
        return three
    if chars == 2:
        return two
    msg = f"chars = {chars!r}: a scan value has 2 or 3 characters"
    raise CommandRangeError(msg)


def chars_per_value(command: str) -> int | None:
    """Characters per scan value for a scan command: 3 (GD/MD), 2 (GS/MS), else None."""
    return {"GD": 3, "MD": 3, "GS": 2, "MS": 2}.get(command[:2])


def value_count(start_step: int, end_step: int, cluster: int) -> int:
    """How many values a scan of steps ``start..end`` with ``cluster`` carries (§3.1)."""
    group = max(cluster, 1)
    return -(-(end_step - start_step + 1) // group)
