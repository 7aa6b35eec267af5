"""A simulated base's boot: the silence after a power-on or reset, its banner, and a reset on DTR.

Modelled on an Arduino-class controller (public: the Arduino Uno's schematic and its "auto-reset"
documentation, arduino.cc, "Automatic (Software) Reset"): the USB-serial chip's DTR output reaches the
MCU's RESET pin through a 100 nF capacitor, so the moment the host *asserts* DTR (as a port opened with
pyserial's defaults does) the MCU resets. It then runs its bootloader (optiboot waits about 0.5 s
for an upload, older ones 1-2 s: ``boot_s``), starts the firmware, which prints a banner, and serves
with everything forgotten: no session, odometry at 0, its clock restarting from 0, a motion cut (the
motor drivers lose their enable), no event sent for it. Input that arrives while it boots is lost.
The banner may end without a line end (a prompt): the next reply then shares its line.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from fakes.robot_motion import fraction_at
from fakes.robot_stream import BaseClock

#: what the firmware prints when it starts (the last piece a prompt without a line end)
DEFAULT_BANNER = b"\r\nRita base bootloader v2\r\nfirmware sim-1.0 starting, 115200 8N1\r\nready> "


@dataclass
class Boot:
    """The boot state of a base: ``boot_s`` of silence after a start, then ``banner``; ``reset_on_dtr``
    makes an asserted DTR restart it. A base made with ``boot_s`` > 0 is booting at its power-on."""

    boot_s: float = 0.0
    banner: bytes = DEFAULT_BANNER
    reset_on_dtr: bool = False
    at_power_on: bool = True  # False: the base was up before the test began
    until: float = -math.inf  # the fake's clock time the boot ends
    announced: bool = True  # the banner of the last start went out
    dtr: bool = False  # the line as the host last set it (a closed port: low)
    resets: int = 0

    def power_on(self, now: float) -> None:
        """Powered on at ``now``: a base with a boot time boots (silent, then its banner)."""
        if self.boot_s > 0 and self.at_power_on:
            self.start(now)

    def start(self, now: float) -> None:
        self.until, self.announced = now + self.boot_s, not self.banner

    def booting(self, now: float) -> bool:
        return now < self.until

    def banner_due(self, now: float) -> bytes | None:
        """The banner, once, when the boot is over."""
        if self.announced or self.booting(now):
            return None
        self.announced = True
        return self.banner

    def set_dtr(self, on: bool) -> bool:
        """The host set DTR; True when that resets the MCU (an assertion edge, with auto-reset)."""
        edge = on and not self.dtr
        self.dtr = on
        return edge and self.reset_on_dtr


def reboot(base: Any, now: float) -> None:
    """Restart ``base`` (a FakeBase, its lock held) at clock time ``now``: the wheels stop where they are,
    and every state of the firmware starts afresh."""
    m = base.motion
    if m is not None:  # the motors lose their enable: the robot stops there, no event is sent
        f = fraction_at(m, now)
        base._place(f)
        m.fault_at = f  # its path ends there (pose_at)
        base._last_motion = (m, now)
        base.motion = None
    base.odometry = (0.0, 0.0, 0.0)
    base.state, base.fault = "IDLE", ""
    base.session = 1
    base.watchdog.timeout_s = None
    base._last_motion_cmd = None
    base.base_clock = BaseClock(now, 0.0, base.base_clock.drift_ppm)  # its counter restarts from 0
    base.streams.clock = base.base_clock
    base.streams.set_rate(0.0, now)
    base._out.clear()
    base._stream_out.clear()
    base.boot.resets += 1
    base.boot.start(now)
