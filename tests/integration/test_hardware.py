"""The link against a real FlightCtrl: opt in with ``MKFLIGHT_MK_PORT=/dev/serial/by-id/...``.

Run on the bench with the props off: ``MKFLIGHT_MK_PORT=... python -m pytest -m hardware``.
It takes no control (Config is never set) and ends by sending Config = 0.
"""

from __future__ import annotations

import itertools
import math
import os
import statistics

import pytest

from mkflight.config import Config
from mkflight.conversions import NS_PER_S
from mkflight.io.serial import open_serial
from mkflight.mk.link import LinkSettings, MkLink
from mkflight.mk.units import MkCalibration

PORT = os.environ.get("MKFLIGHT_MK_PORT")
pytestmark = [
    pytest.mark.hardware,
    pytest.mark.skipif(PORT is None, reason="set MKFLIGHT_MK_PORT to a real FlightCtrl"),
]


async def test_real_fc_streams_plausible_samples_at_about_53_ms() -> None:
    assert PORT is not None
    cfg = Config()
    stream = await open_serial(PORT, cfg.mk.baudrate)
    link = MkLink(stream, LinkSettings.from_config(cfg), MkCalibration.from_config(cfg.mk))
    async with link:
        version = await link.connect()
        assert not version.has_hardware_error
        link.subscribe()
        samples = [await link.next_sample(timeout_s=2.0) for _ in range(60)]
    gaps_s = [(b.t_ns - a.t_ns) / NS_PER_S for a, b in itertools.pairwise(samples)]
    assert 0.045 <= statistics.median(gaps_s) <= 0.065
    for s in samples:  # standing still: the specific force is about g
        norm = math.sqrt(s.acc_x_mps2**2 + s.acc_y_mps2**2 + s.acc_z_mps2**2)
        assert 8.5 <= norm <= 11.0
        assert 6.0 <= s.battery_v <= 26.0
    assert link.stats.confirms >= 1  # the release frames were confirmed
