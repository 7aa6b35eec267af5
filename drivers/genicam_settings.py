"""Write :class:`~drivers.camera_settings.CameraSettings` to a GenICam node map in one fixed order.

The order is the known state (:data:`KNOWN_STATE`: AcquisitionMode, ReverseX, ReverseY), PixelFormat,
Width/Height/OffsetX/OffsetY, ExposureTime, Gain,
AcquisitionFrameRateEnable/AcquisitionFrameRate, TriggerSelector/TriggerMode/
TriggerSource, PtpEnable with PtpSlaveOnly, then chunk data and the GigE transport (packet size,
throughput limit, packet resend, stream buffers; :mod:`drivers.genicam_transport`,
whose :func:`~drivers.genicam_transport.apply_all` runs the whole sequence). Pixel format comes
first because it changes the ranges of the geometry features; geometry comes before exposure and
frame rate because
the maximum frame rate depends on the region of interest.

Rules (the daemon is master, the camera is told what to be):

* ``None`` in the settings leaves that feature alone.
* A feature the device lacks (or cannot write right now) is not an error: it is
  reported through ``warn`` and the rest is applied.
* A value that does not change anything is not written (GigE writes cost a round
  trip, and some features reset internal state when written).
* A pixel format :mod:`drivers.pixel_formats` cannot decode, or one the camera's
  PixelFormat node does not offer, raises :class:`~drivers.base.DeviceError` naming the
  supported or offered ones.
* A bad ROI raises :class:`~drivers.base.DeviceError` naming the
  value and the allowed range; exposure, gain and frame rate are clamped into the
  device's range with a warning, because their limits move with other features.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

from genicam import genapi

from drivers import pixel_formats
from drivers.base import DeviceError
from drivers.camera_settings import CameraSettings

Warn = Callable[[str], None]

# GenApi access modes (EAccessMode): NI=0, NA=1, WO=2, RO=3, RW=4.
_NA = 1
_RO = 3
_RW = 4
_INT, _BOOL, _CMD, _FLOAT, _ENUM = 2, 3, 4, 5, 9
#: features another program may have left changed, set at every open whatever the settings say (SFNC
#: names): free run until stopped (SingleFrame or MultiFrame would stall a stream), and the image as the
#: sensor sees it (a mirrored image starts on another colour: BayerRG becomes BayerGR, which this
#: driver's decoder does not read)
KNOWN_STATE: tuple[tuple[str, Any], ...] = (("AcquisitionMode", "Continuous"), ("ReverseX", False),
                                            ("ReverseY", False))


def find_node(nm: Any, name: str) -> Any | None:
    """The node called ``name`` when it exists and is available, else None."""
    if nm is None:
        return None
    try:
        node = nm.get_node(name)
    except (genapi.GenericException, AttributeError):
        return None
    try:
        if node.get_access_mode() <= _NA:
            return None
    except genapi.GenericException:
        return None
    return node


def _kind(node: Any) -> int:
    return int(node.node.principal_interface_type)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        return math.isclose(float(a), float(b), rel_tol=1e-6, abs_tol=1e-9)
    return bool(a == b)


@dataclass
class SettingsWriter:
    """Writes single features, skipping no-op writes and recording what the device reports."""

    nm: Any
    warn: Warn
    applied: dict[str, Any] = field(default_factory=dict)
    writes: int = 0
    #: who lacks a feature, in warnings: the camera, or the GenTL producer's data stream
    owner: str = "camera"

    def read(self, name: str) -> Any | None:
        """Current value of a readable feature, or None."""
        node = find_node(self.nm, name)
        if node is None or node.get_access_mode() not in (_RO, _RW):
            return None
        try:
            return node.value
        except genapi.GenericException:
            return None

    def has(self, name: str) -> bool:
        return find_node(self.nm, name) is not None

    def write(self, name: str, value: Any, *, clamp: bool = False, quiet: bool = False) -> bool:
        """Set ``name`` to ``value``; False (with a warning unless ``quiet``) if impossible."""
        node = find_node(self.nm, name)
        if node is None:
            if not quiet:
                self.warn(f"{self.owner} has no {name}; {name}={value!r} not applied")
            return False
        if node.get_access_mode() != _RW:
            if not quiet:
                self.warn(f"{self.owner}'s {name} is not writable now (access mode "
                          f"{node.get_access_mode()}); {name}={value!r} not applied")
            return False
        kind = _kind(node)
        value = self._check(name, node, kind, value, clamp)
        current = node.value
        if not _same(current, value):
            try:
                node.value = value
            except genapi.GenericException as exc:
                raise DeviceError(f"camera refused {name}={value!r}: {exc}", code="bad_setting") from None
            self.writes += 1
        self.applied[name] = node.value
        return True

    def _check(self, name: str, node: Any, kind: int, value: Any, clamp: bool) -> Any:
        if kind == _ENUM:
            symbols = tuple(node.symbolics)
            if value not in symbols:
                raise DeviceError(f"camera has no {name} {value!r} (it offers {', '.join(symbols)})",
                                  code="bad_setting")
            return value
        if kind == _BOOL:
            return bool(value)
        if kind == _INT:
            v = int(value)
            lo, hi, inc = int(node.min), int(node.max), int(node.inc)
            if v < lo or v > hi or (inc > 1 and (v - lo) % inc):
                raise DeviceError(f"{name}={value!r} is outside the camera's range {lo}..{hi} "
                                  f"(step {inc})", code="bad_setting")
            return v
        if kind == _FLOAT:
            x = float(value)
            lo_f, hi_f = float(node.min), float(node.max)
            if lo_f <= x <= hi_f:
                return x
            if clamp:
                c = min(max(x, lo_f), hi_f)
                self.warn(f"{name}={x:g} is outside the camera's range {lo_f:g}..{hi_f:g}; using {c:g}")
                return c
            raise DeviceError(f"{name}={value!r} is outside the camera's range {lo_f:g}..{hi_f:g}",
                              code="bad_setting")
        return value

    def execute(self, name: str) -> bool:
        """Run a command feature; False if the device lacks it."""
        node = find_node(self.nm, name)
        if node is None or _kind(node) != _CMD:
            return False
        node.execute()
        return True


def set_trigger_mode(w: SettingsWriter, software: bool) -> bool:
    """Select FrameStart and switch software triggering on or off.

    Returns True when the device can be software-triggered (TriggerMode=On,
    TriggerSource=Software and a TriggerSoftware command all exist). Free run on a
    device without triggers is its natural state, so only the software request warns.
    """
    quiet = not software
    if w.has("TriggerSelector"):
        sel = find_node(w.nm, "TriggerSelector")  # not None: w.has() found it
        if sel is not None and "FrameStart" in tuple(sel.symbolics):
            w.write("TriggerSelector", "FrameStart")
        elif not quiet:
            w.warn("camera's TriggerSelector has no FrameStart; using its current selector")
    elif not quiet:
        w.warn("camera has no TriggerSelector; TriggerSelector='FrameStart' not applied")
    ok = w.write("TriggerMode", "On" if software else "Off", quiet=quiet)
    if software:
        ok = w.write("TriggerSource", "Software") and ok
        if not w.has("TriggerSoftware"):
            w.warn("camera has no TriggerSoftware command")
            ok = False
        if not ok:
            w.warn("camera cannot be software-triggered; trigger() takes the next free-run frame")
    return ok and software


def apply_known_state(w: SettingsWriter) -> None:
    """:data:`KNOWN_STATE` where the camera has it; a mirror it cannot switch off is an error naming it."""
    for name, value in KNOWN_STATE:
        if w.has(name) and not _same(w.read(name), value):  # already so: nothing to write (nor to refuse)
            w.write(name, value)
    for axis in ("ReverseX", "ReverseY"):
        if w.read(axis):
            raise DeviceError(f"camera's {axis} is on and cannot be switched off: a mirrored image's Bayer "
                              f"pattern is not the one its PixelFormat names", code="bad_setting")


def _ptp(w: SettingsWriter, on: bool) -> None:
    """PtpEnable, and PtpSlaveOnly with it, as LUCID's guidance and LUCID-based public code do (ROS 2 nodes
    derived from lucidvisionlabs/arena_camera_ros2 write both): without it the camera takes part in the
    IEEE 1588 master election and becomes master when no better clock runs."""
    if w.write("PtpEnable", on) and on:  # a camera without PTP has nothing to keep from mastering
        w.write("PtpSlaveOnly", True)


def apply_settings(w: SettingsWriter, s: CameraSettings) -> bool:
    """Apply ``s`` in the documented order; returns whether software triggering works."""
    if s.trigger not in ("software", "free"):
        raise DeviceError(f"camera trigger setting {s.trigger!r} is not 'software' or 'free'",
                          code="bad_setting")
    apply_known_state(w)
    if s.pixel_format is not None:
        if s.pixel_format not in pixel_formats.FORMATS:  # the camera might offer it; we cannot decode it
            raise DeviceError(f"PixelFormat {s.pixel_format!r} cannot be decoded (supported: "
                              f"{', '.join(pixel_formats.FORMATS)})", code="bad_setting")
        w.write("PixelFormat", s.pixel_format)
    # Zero the offsets first when they will be rewritten: a wider ROI may not fit
    # next to the old offset (Width.max = sensor width - OffsetX).
    for off, want in (("OffsetX", s.offset_x), ("OffsetY", s.offset_y)):
        if want is not None and w.read(off) not in (None, 0, want):
            w.write(off, 0, quiet=True)
    for name, want in (("Width", s.width), ("Height", s.height),
                       ("OffsetX", s.offset_x), ("OffsetY", s.offset_y)):
        if want is not None:
            w.write(name, want)
    if s.exposure_us is not None:
        w.write("ExposureAuto", "Off", quiet=True)
        w.write("ExposureTime", s.exposure_us, clamp=True)
    if s.gain_db is not None:
        w.write("GainAuto", "Off", quiet=True)
        w.write("Gain", s.gain_db, clamp=True)
    if s.frame_rate_hz is not None:
        # SFNC makes the enable switch optional: without it the rate is always in force.
        w.write("AcquisitionFrameRateEnable", True, quiet=True)
        w.write("AcquisitionFrameRate", s.frame_rate_hz, clamp=True)
    software = set_trigger_mode(w, s.trigger == "software")
    if s.ptp is not None:
        _ptp(w, bool(s.ptp))
    return software
