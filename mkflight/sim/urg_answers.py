"""What the emulated URG-04LX says: fixed info texts, request checks and scan messages.

Pure helpers of :mod:`mkflight.sim.urg` (``protocols/scip2.md`` §3-5). The VV, PP and II
texts are those recorded from a real URG-04LX (vectors SC-03..SC-05); requests are checked
in the order that gives the statuses of SC-10 and SC-17..SC-20; scan values follow §3.1
(clusters) and §5 (> DMAX sent as 0, 2-character overflow sent as 0, dead zone 19).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

from mkflight.urg.codec import (
    LF,
    MAX_STEP,
    MAX_TAG_CHARS,
    data_blocks,
    encode_values,
    info_line,
    status_line,
    timestamp_line,
)
from mkflight.urg.units import URG_04LX, SensorParams

DEAD_ZONE_CODE: Final = 19  # what the emulator sends for steps outside AMIN..AMAX (§8)
TWO_CHAR_MAX: Final = 4095  # the largest value 2 characters hold (§2.4)
_TAG_CHARS: Final = frozenset(
    b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789 ._+@"
)


@dataclass(frozen=True, slots=True)
class UrgIdentity:
    """The texts of VV, PP and II: by default those of a recorded URG-04LX (SC-03..05)."""

    vendor: str = "Hokuyo Automatic Co.,Ltd."
    product: str = "SOKUIKI Sensor URG-04LX"
    firmware: str = "3.1.04(02/Aug./2007)"
    protocol: str = "SCIP 2.0"
    serial: str = "H0706400"
    params: SensorParams = URG_04LX
    speed: str = "Initial(600[rpm])<-Default setting by user"
    measure_mode: str = "CLASSIC"
    bit_rate: str = "19200[bps]<-Default setting by user"
    state: str = "Sensor works well."


@dataclass(frozen=True, slots=True)
class ScanRequest:
    """A checked GD/GS/MD/MS request (§3.1); ``head`` is the echo without the tag."""

    head: bytes
    tag: bytes  # b"" or b";string"
    start_step: int
    end_step: int
    cluster: int
    chars: int
    interval: int = 0
    count: int = 0

    @property
    def is_stream(self) -> bool:
        """MD/MS (a stream) rather than GD/GS (one scan)."""
        return self.head[:1] == b"M"

    def echo(self, remaining: int | None = None) -> bytes:
        """The echo; for a stream message the count digits hold ``remaining`` (§3.2)."""
        if remaining is None or not self.is_stream:
            return self.head + self.tag
        return self.head[:-2] + b"%02d" % remaining + self.tag


def status_reply(echo: bytes, status: str) -> bytes:
    """``echo LF status sum LF LF`` (§2.2)."""
    return echo + LF + status_line(status) + LF + LF


def info_reply(echo: bytes, lines: Sequence[tuple[str, str]]) -> bytes:
    """``echo LF 00P LF`` then ``KEY:value;S LF`` lines, then LF (§2.3, SC-03)."""
    body = b"".join(info_line(k, v) + LF for k, v in lines)
    return echo + LF + status_line("00") + LF + body + LF


def vv_lines(who: UrgIdentity) -> list[tuple[str, str]]:
    """VV: vendor, product, firmware, protocol, serial (SC-03)."""
    return [
        ("VEND", who.vendor),
        ("PROD", who.product),
        ("FIRM", who.firmware),
        ("PROT", who.protocol),
        ("SERI", who.serial),
    ]


def pp_lines(who: UrgIdentity) -> list[tuple[str, str]]:
    """PP: model and the seven numeric parameters (SC-04, §5)."""
    p = who.params
    return [
        ("MODL", p.model),
        ("DMIN", str(p.dmin_mm)),
        ("DMAX", str(p.dmax_mm)),
        ("ARES", str(p.ares_steps)),
        ("AMIN", str(p.amin_step)),
        ("AMAX", str(p.amax_step)),
        ("AFRT", str(p.afront_step)),
        ("SCAN", str(p.scan_rpm)),
    ]


def ii_lines(who: UrgIdentity, *, laser_on: bool, timer_ms: int) -> list[tuple[str, str]]:
    """II: state, with the timer as 6 hex digits (SC-05)."""
    return [
        ("MODL", who.params.model),
        ("LASR", "ON" if laser_on else "OFF"),
        ("SCSP", who.speed),
        ("MESM", who.measure_mode),
        ("SBPS", who.bit_rate),
        ("TIME", f"{timer_ms:06X}"),
        ("STAT", who.state),
    ]


def tag_status(tag: bytes) -> str | None:
    """``0G`` for a string > 16 characters, ``0H`` for a bad character, else None (§4)."""
    text = tag[1:]
    if len(text) > MAX_TAG_CHARS:
        return "0G"
    if any(c not in _TAG_CHARS for c in text):
        return "0H"
    return None


def parse_scan_request(head: bytes, tag: bytes) -> ScanRequest | str:
    """Check a GD/GS/MD/MS request; return it, or the error status (§3.1, §4).

    Order: too few (``0C``) or extra (``0D``) characters, then each field's "not
    numeric" status (01, 02, 03, 06, 07), then end > 768 (04), then end < start (05).
    """
    stream = head[:1] == b"M"
    params = head[2:]
    need = 13 if stream else 10
    if len(params) < need:
        return "0C"
    if len(params) > need:
        return "0D"
    fields = [(params[0:4], "01"), (params[4:8], "02"), (params[8:10], "03")]
    if stream:
        fields += [(params[10:11], "06"), (params[11:13], "07")]
    for text, status in fields:
        if not text.isdigit():
            return status
    start, end, cluster = int(params[0:4]), int(params[4:8]), int(params[8:10])
    if end > MAX_STEP:
        return "04"
    if end < start:
        return "05"
    return ScanRequest(
        head=head,
        tag=tag,
        start_step=start,
        end_step=end,
        cluster=cluster,
        chars=3 if head[1:2] == b"D" else 2,
        interval=int(params[10:11]) if stream else 0,
        count=int(params[11:13]) if stream else 0,
    )


def cluster_values(values: Sequence[int], cluster: int, dmin_mm: int) -> list[int]:
    """Group ``cluster`` neighbouring values into their smallest valid one (§3.1, SC-14).

    Error codes (< DMIN) are excluded; a group of only error codes gives its smallest
    code. A partial last group still gives a value. Cluster 0 and 1 mean no grouping.
    """
    if cluster <= 1:
        return list(values)
    out: list[int] = []
    for i in range(0, len(values), cluster):
        group = values[i : i + cluster]
        valid = [v for v in group if v >= dmin_mm]
        out.append(min(valid) if valid else min(group))
    return out


def scan_values(request: ScanRequest, measured: Sequence[int], params: SensorParams) -> list[int]:
    """The values a scan message carries, from the per-step ranges of ``start..end`` (mm).

    Values > DMAX (and negative ones) become 0 (§5), then clusters are formed, then
    values that do not fit 2 characters become 0 on GS/MS (SC-13).
    """
    clean = [v if 0 <= v <= params.dmax_mm else 0 for v in measured]
    values = cluster_values(clean, request.cluster, params.dmin_mm)
    if request.chars == 2:
        values = [v if v <= TWO_CHAR_MAX else 0 for v in values]
    return values


def scan_message(
    echo: bytes, status: str, timestamp_ms: int, values: Sequence[int], chars: int
) -> bytes:
    """``echo LF status LF timestamp LF blocks LF`` (§2.5, §3.2, SC-11/SC-15)."""
    return (
        echo
        + LF
        + status_line(status)
        + LF
        + timestamp_line(timestamp_ms)
        + LF
        + data_blocks(encode_values(values, chars))
        + LF
    )


def corrupt_last_sum(reply: bytes) -> bytes:
    """Change the sum character of the reply's last line, so the client drops it (SC-21)."""
    end = len(reply) - 2  # the last line's LF; the reply ends in LF LF
    pos = end - 1
    if pos < 0 or reply[end:] != LF + LF:
        return reply
    bad = 0x30 + (reply[pos] - 0x30 + 1) % 64
    return reply[:pos] + bytes((bad,)) + reply[pos + 1 :]
