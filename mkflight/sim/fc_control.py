"""What the emulated FlightCtrl flies: the pilot's sticks, ExternControl and its hold.

Part of the pure FC model (:mod:`mkflight.sim.fc`), split out so that a vehicle model
can read the applied command without knowing the serial protocol. The rules are
``mk-serial.md`` §5.4 (PPM channels, stick gas), §7.3 (the ``ExternalControl`` setting)
and §7.4 (extern sticks added, gas capped, the PcZugriff hold counter). Time is the FC's
tick number, given by the caller.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Final

from mkflight.config import SimFcConfig
from mkflight.mk.messages import EC_VALID, ExternControl

HOLD_RELOAD_COUNTS: Final = 255  # PcZugriff after an 'a','b','d','h','l','p','t' (§7.4)
HOLD_BOOT_COUNTS: Final = 100  # PcZugriff at boot (§7.4)
HOLD_STEP_TICKS: Final = 20  # PcZugriff counts down every 20 ticks (§7.4)
EXTERN_MIN_SETTING: Final = 129  # ExternalControl must be > 128 (§7.3)
EXTERN_POTI_SETTING: Final = 248  # 248..255: take the value from poti 8..1 (§7.3)
STICK_GAS_OFFSET: Final = 120  # stick gas = PPM_in[gas] + 120 (§5.4)
POTI_OFFSET: Final = 127  # poti value = PPM_in[channel] + 127 (an approximation)
PPM_CHANNELS: Final = 26  # PPM_in[0..25], 0 unused
CH_GAS, CH_ROLL, CH_NICK, CH_YAW, CH_POTI1 = 1, 2, 3, 4, 5  # default channel map (§5.4)
INT16_MIN, INT16_MAX = -32768, 32767


@dataclass(frozen=True, slots=True)
class FcCommand:
    """The sticks the FC flies, before its ``Stick_P`` scaling (§7.4).

    nick/roll: pilot stick + extern value while extern control is active (+ nick = nose
    down, + roll = left side down); yaw: the negated yaw channel + extern yaw; gas:
    min(stick gas, extern gas) while active, else the stick gas.
    """

    nick: int
    roll: int
    yaw: int
    gas: int


class FcControls:
    """The pilot's receiver channels, the last ExternControl and the hold counter.

    The hold counter (PcZugriff) steps down on a free-running grid of 20 ticks from
    boot; when it reaches 0 the FC sets the stored Config to 0, which ends extern
    control ≈ 5.2 s after the last hold frame (§7.4).
    """

    def __init__(self, settings: SimFcConfig) -> None:
        self.settings = settings
        self._ppm = [0] * PPM_CHANNELS
        self._ppm[CH_GAS] = settings.stick_gas - STICK_GAS_OFFSET
        # What a fault test checks at the FC's end of the wire: every ExternControl taken.
        self.extern_frames = 0
        self.max_tilt_counts = 0.0  # |(nick, roll)|
        self.max_yaw_counts = 0
        self.max_gas_counts = 0
        self.min_gas_counts = 255
        self.released_by = ""  # what last ended extern control: command, hold counter, reboot
        self.reset()

    def reset(self) -> None:
        """What a rebooted FC starts with: no extern command, hold counter 100.

        The channels are the pilot's transmitter, not FC state: they are kept.
        """
        self.last_extern: ExternControl | None = None
        self._hold_tick = 0
        self._hold_counts = HOLD_BOOT_COUNTS
        self.released_by = "reboot"

    def receive(self, ec: ExternControl) -> None:
        """An ExternControl frame was taken: store it and note its values (see __init__)."""
        self.last_extern = ec
        self.extern_frames += 1
        nick, roll, yaw, gas = int(ec.nick), int(ec.roll), int(ec.yaw), int(ec.gas)
        self.max_tilt_counts = max(self.max_tilt_counts, math.hypot(nick, roll))
        self.max_yaw_counts = max(self.max_yaw_counts, abs(yaw))
        self.max_gas_counts = max(self.max_gas_counts, gas)
        self.min_gas_counts = min(self.min_gas_counts, gas)
        if not int(ec.config) & EC_VALID:
            self.released_by = "command"

    # ----------------------------------------------------------------- hold
    def reload_hold(self, tick: int) -> None:
        """A hold frame was handled at ``tick``: PcZugriff = 255."""
        self._hold_tick, self._hold_counts = tick, HOLD_RELOAD_COUNTS

    def hold_zero_tick(self) -> int:
        """The tick at which the hold counter reaches 0."""
        return (self._hold_tick // HOLD_STEP_TICKS + self._hold_counts) * HOLD_STEP_TICKS

    def hold_counts_at(self, tick: int) -> int:
        """PcZugriff at ``tick`` (not before the last reload)."""
        steps = tick // HOLD_STEP_TICKS - self._hold_tick // HOLD_STEP_TICKS
        return max(0, self._hold_counts - max(0, steps))

    def expire(self, tick: int) -> None:
        """Set the stored Config to 0 if the hold counter has run out by ``tick``."""
        ec = self.last_extern
        if ec is not None and self.extern_requested and tick >= self.hold_zero_tick():
            self.last_extern = replace(ec, config=0)
            self.released_by = "hold counter"

    # ----------------------------------------------------------------- extern
    @property
    def extern_requested(self) -> bool:
        """The stored ExternControl (still) has Config bit 0 set."""
        ec = self.last_extern
        return ec is not None and bool(int(ec.config) & EC_VALID)

    @property
    def extern_allowed(self) -> bool:
        """The ExternalControl setting, or the poti it names, is above 128 (§7.3)."""
        setting = self.settings.external_control
        if setting >= EXTERN_POTI_SETTING:
            channel = CH_POTI1 + 255 - setting
            setting = max(0, min(255, self._ppm[channel] + POTI_OFFSET))
        return setting >= EXTERN_MIN_SETTING

    @property
    def extern_active(self) -> bool:
        """ExternControl is being applied: Config bit 0 and the setting allow it."""
        return self.extern_requested and self.extern_allowed

    # ----------------------------------------------------------------- sticks
    @property
    def stick_gas(self) -> int:
        """The pilot's gas: ``PPM_in[gas] + 120``, not below 0 (§5.4)."""
        return max(0, self._ppm[CH_GAS] + STICK_GAS_OFFSET)

    @property
    def ppm_channels(self) -> tuple[int, ...]:
        """``PPM_in[0..25]`` as the 'P' answer carries it."""
        return tuple(self._ppm)

    def set_ppm(self, channels: Mapping[int, int]) -> None:
        """Set receiver channels ``{channel: value}`` (1..25, about ±120); others keep.

        Raises:
            ValueError: a channel outside 1..25 or a value outside int16.
        """
        for channel, value in channels.items():
            if not 1 <= channel < PPM_CHANNELS or not INT16_MIN <= value <= INT16_MAX:
                msg = f"PPM channel {channel} = {value} outside 1..25 / int16"
                raise ValueError(msg)
        for channel, value in channels.items():
            self._ppm[channel] = value

    def set_sticks(
        self,
        *,
        nick: int | None = None,
        roll: int | None = None,
        yaw: int | None = None,
        gas: int | None = None,
    ) -> None:
        """Move the pilot's sticks: channel values, and ``gas`` as stick gas (channel + 120)."""
        values = {CH_NICK: nick, CH_ROLL: roll, CH_YAW: yaw}
        if gas is not None:
            values[CH_GAS] = gas - STICK_GAS_OFFSET
        self.set_ppm({ch: v for ch, v in values.items() if v is not None})

    def effective_command(self) -> FcCommand:
        """The sticks the FC flies: pilot + extern while active, gas capped (§7.4)."""
        nick, roll, yaw = self._ppm[CH_NICK], self._ppm[CH_ROLL], -self._ppm[CH_YAW]
        gas = self.stick_gas
        ec = self.last_extern
        if ec is not None and self.extern_active:
            nick += int(ec.nick)
            roll += int(ec.roll)
            yaw += int(ec.yaw)
            gas = min(gas, int(ec.gas))
        return FcCommand(nick=nick, roll=roll, yaw=yaw, gas=gas)
