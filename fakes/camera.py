"""Simulated nadir camera: renders what Rita's camera sees in the simulated world.

URL ``sim:`` with options:

* ``size=reduced|full|WxH``: 1000×750 (default) or 4024×3036, both with the
  sensor's field of view; ``WxH`` is any other size with that field of view
  (keep the sensor's aspect ratio), handy for fast tests.
* ``fps``: free-run rate; default the settings' ``frame_rate_hz`` (else 5).
* ``noise=0|1``: sensor noise on (default) or off. Noise comes from
  ``world.rng("camera.noise")``, so a given seed, pose sequence and frame order
  always give the same pixels.
* ``prerender=N``: render N frames once at ``open()`` and cycle them (for
  throughput benchmarks; the images then no longer follow the robot).
* ``serial``: the serial number reported (default ``SIM-0001``).
* Fault knobs, each counted in ``status()``: ``drop_every=N`` drops every Nth
  frame (a gap in frame ids; a dropped triggered frame raises DeviceTimeout),
  ``incomplete_every=N`` delivers every Nth frame incomplete (rows from a
  seeded point down are zero, ``incomplete_count`` goes up), and
  ``disconnect_after=N`` raises DeviceLost once a connection has delivered N
  frames; ``close()`` + ``open()`` connects again and re-applies the settings.
* GigE link (:mod:`fakes.gige_link`'s model, counted in ``status()["link"]``):
  ``packet_loss=P`` is the per-packet loss chance at line rate (default 0: a perfect link;
  a throughput limit below 95 % of the link cuts it tenfold), ``path_mtu=N`` the largest
  packet the path passes (default 9000; 1500 = a NIC without jumbo frames). A frame the link
  leaves incomplete is delivered like an ``incomplete_every`` one.

How it differs from the real PHX122S: images come from :class:`fakes.render.Renderer`
(planar world, Gaussian noise); exposure and gain only scale the rendered
intensity (no motion blur, saturation physics or noise change); there is no
GigE bandwidth limit, so the rate is only limited by rendering (about 1 s per
reduced-size frame unless ``prerender`` is used; a colour frame about 3 s)
and one render may overrun ``pump``'s timeout; one camera offers both sensor
profiles of the family, :data:`PIXEL_FORMATS` (the configured PixelFormat picks the
mono or the RGGB Bayer colour sensor, :mod:`fakes.colour`; frames are packed into the
format's wire layout and decoded by :mod:`drivers.pixel_formats`, like a GenICam
camera's); Bayer ROIs need even offsets; no events; PTP only with the ``ptp`` option (else
``status()["ptp"]`` says unavailable); with ``chunks`` on, the header's chunk values are the applied
exposure and gain and the device timestamp; the frame is
rendered at the pose the robot has when its exposure starts (no motion during the exposure, no
rolling shutter); device timestamps come from the camera's own clock, :mod:`fakes.camera_clock`
(options ``clock_offset_s``, ``clock_drift_ppm``, ``ptp``, ``ptp_offset_ns``, ``latency_ms``), and
``host_time_ns`` is the simulated arrival (exposure start + exposure + wire time + latency), not
when the render finished; the header's ``sim_t_mid_ns`` is the exposure's true mid-time; frame ids
run on across reconnects instead of restarting. Width/Height/OffsetX/OffsetY
crop the rendered image like a sensor ROI.
"""
from __future__ import annotations

import logging
import math
import threading
import time
import weakref
from dataclasses import asdict
from typing import Any, Protocol

import numpy as np

from drivers.base import Camera, DeviceError, DeviceLost, DeviceTimeout, DeviceURL, Emit, Frame, no_emit
from drivers.camera_settings import CameraSettings, desired
from drivers import pixel_formats
from fakes import camera_clock
from fakes.colour import ColourRenderer, sensor_image
from fakes.gige_link import GigELink, LinkSettings, sim_transport
from fakes.render import Renderer
from fakes import worlds
from fakes.world import World

log = logging.getLogger(__name__)

#: PixelFormat values the simulated camera offers (PHX122S mono and colour models)
PIXEL_FORMATS = ("Mono8", "Mono12p", "Mono12Packed", "Mono16", "BayerRG8", "BayerRG12p", "RGB8")
#: exposure at which the renderer's black/white levels hold; other exposures scale linearly
NOMINAL_EXPOSURE_US = 2000.0

# Rays cost seconds (reduced) to a minute (full size) to compute, so renderers are
# shared per world and size, across reconnects and camera instances.
_RENDERERS: "weakref.WeakKeyDictionary[World, dict[tuple, Renderer]]" = weakref.WeakKeyDictionary()
_RENDERERS_LOCK = threading.Lock()


class Pacing(Protocol):
    """The clock the free-run schedule keeps (``time`` unless a test counts virtual time): one per camera,
    so a virtual clock never reaches another camera pumped in another thread of the same process."""

    def monotonic(self) -> float: ...

    def sleep(self, seconds: float, /) -> None: ...


def renderer_for(world: World, size: tuple[int, int], colour: bool = False) -> Renderer:
    """The cached (grey or Bayer colour) renderer of ``world`` at ``size`` (created on first use)."""
    with _RENDERERS_LOCK:
        per_world = _RENDERERS.setdefault(world, {})
        key = (size, True) if colour else size
        r = per_world.get(key)
        if r is None:
            r = per_world[key] = (ColourRenderer if colour else Renderer)(world, size)
        return r


def parse_size(url: DeviceURL, world: World) -> tuple[int, int]:
    """Image size from the ``size`` option: reduced, full or WxH."""
    text = url.option("size", "reduced")
    if text == "reduced":
        return tuple(world.params.reduced_size)  # type: ignore[return-value]
    if text == "full":
        return tuple(world.params.full_size)  # type: ignore[return-value]
    w, sep, h = text.lower().partition("x")
    if sep and w.isdigit() and h.isdigit() and int(w) >= 8 and int(h) >= 8:
        return int(w), int(h)
    raise ValueError(f"camera URL {url.raw!r}: size={text!r} is not 'reduced', 'full' or WxH "
                     "(e.g. 200x151, at least 8x8)")


def _count(url: DeviceURL, key: str) -> int:
    """A non-negative integer option (0 = off)."""
    n = url.option(key, 0, int)
    if n < 0:
        raise ValueError(f"camera URL {url.raw!r}: {key}={n} must be >= 0")
    return n


class SimCamera(Camera):
    """Renders the simulated world at the robot's pose; see the module docstring."""

    OPTIONS = frozenset({"size", "fps", "noise", "prerender", "serial", "drop_every", "incomplete_every",
                         "disconnect_after", "packet_loss", "path_mtu", worlds.OPTION, *camera_clock.OPTIONS})

    def __init__(self, url: DeviceURL, *, emit: Emit = no_emit,
                 settings: CameraSettings | None = None, pacing: Pacing = time) -> None:
        super().__init__(url, emit=emit, settings=settings)
        self.pacing = pacing  # the free run's schedule only; the frames' stamps keep the real clocks
        self.world = worlds.world_for(url)
        self.size = parse_size(url, self.world)
        self.fps: float | None = url.option("fps", None, float)
        if self.fps is not None and not (0 < self.fps < math.inf):
            raise ValueError(f"camera URL {url.raw!r}: fps={self.fps} must be > 0")
        noise = url.option("noise", "1")
        if noise not in ("0", "1"):
            raise ValueError(f"camera URL {url.raw!r}: noise={noise!r} must be 0 or 1")
        self.noise = noise == "1"
        self.prerender = _count(url, "prerender")
        self.serial: str = url.option("serial", "SIM-0001")
        self.drop_every = _count(url, "drop_every")
        self.incomplete_every = _count(url, "incomplete_every")
        self.disconnect_after = _count(url, "disconnect_after")
        loss = url.option("packet_loss", 0.0, float)
        if not 0.0 <= loss < 1.0:
            raise ValueError(f"camera URL {url.raw!r}: packet_loss={loss} must be in [0, 1)")
        self.path_mtu: int = url.option("path_mtu", 9000, int)
        if self.path_mtu < 576:
            raise ValueError(f"camera URL {url.raw!r}: path_mtu={self.path_mtu} must be >= 576")
        self.link = GigELink(self.world.rng("camera.link"), path_mtu=self.path_mtu,
                             loss_at_line_rate=loss, loss_limited=loss / 10)
        self._link_settings = LinkSettings()
        self.clock = camera_clock.CameraClock.from_url(url, self.world.rng("camera.latency"))
        self._next_link = 0.0
        self._last_link: dict[str, Any] = self.link.stats()
        self._rng = self.world.rng("camera.noise")
        self._cut_rng = self.world.rng("camera.incomplete")
        self._renderer: Renderer | None = None
        self._prerendered: list[np.ndarray] = []
        self._open = False
        self._lost = False
        self._next_due = 0.0
        self._frame_id = 0
        self._frames_this_open = 0
        self.counters = {"opens": 0, "applies": 0, "frames": 0, "renders": 0, "dropped": 0,
                         "incomplete": 0, "disconnects": 0}

    # ------------------------------------------------------------------ lifecycle

    def open(self) -> None:
        """Connect: build (or reuse) the renderer, apply the settings, prerender if asked."""
        if self._open:
            return
        self._apply()
        if self.prerender and not self._prerendered:
            self._prerendered = [self._render() for _ in range(self.prerender)]
        self._open, self._lost = True, False
        self._frames_this_open = 0
        self.counters["opens"] += 1
        if self._want_stream:
            self.start_stream()

    def close(self) -> None:
        self._open = self._streaming = False

    def configure(self, settings: CameraSettings) -> None:
        """Change the desired settings; applied now when open, and at every later open."""
        self.settings = settings
        if self._open:
            self._apply()
            if self.prerender and not self._prerendered:  # the PixelFormat changed
                self._prerendered = [self._render() for _ in range(self.prerender)]

    def _apply(self) -> None:
        s = desired(self.settings)
        warnings: list[str] = []
        fmt = s.pixel_format or "Mono8"
        if fmt not in PIXEL_FORMATS:
            raise DeviceError(f"camera has no PixelFormat {fmt!r} (it offers {', '.join(PIXEL_FORMATS)})",
                              code="bad_setting")
        if s.trigger not in ("software", "free"):
            raise DeviceError(f"camera trigger setting {s.trigger!r} is not 'software' or 'free'",
                              code="bad_setting")
        W, H = self.size
        ox, oy = s.offset_x or 0, s.offset_y or 0
        w, h = s.width or W - ox, s.height or H - oy
        for name, off, ext, full in (("X", ox, w, W), ("Y", oy, h, H)):
            if off < 0 or ext < 1 or off + ext > full:
                raise DeviceError(f"ROI Offset{name}={off} with {'Width' if name == 'X' else 'Height'}"
                                  f"={ext} does not fit the {W}x{H} sensor", code="bad_setting")
            if off % 2 and pixel_formats.lookup(fmt).colour:  # keeps the RGGB phase of the mosaic
                raise DeviceError(f"ROI Offset{name}={off} must be even for {fmt}", code="bad_setting")
        exposure = NOMINAL_EXPOSURE_US if s.exposure_us is None else float(s.exposure_us)
        gain_db = 0.0 if s.gain_db is None else float(s.gain_db)
        if not exposure > 0:
            raise DeviceError(f"ExposureTime={exposure!r} must be > 0", code="bad_setting")
        rate = self.fps if self.fps is not None else (s.frame_rate_hz or 5.0)
        if not rate > 0:
            raise DeviceError(f"frame rate {rate!r} must be > 0", code="bad_setting")
        ptp: dict[str, Any] = {}
        if s.ptp is not None and self.clock.ptp_state is None:
            warnings.append(f"camera has no PtpEnable; PtpEnable={s.ptp!r} not applied")
        elif s.ptp is not None:
            self.clock.ptp_enabled = bool(s.ptp)
            ptp["PtpEnable"] = self.clock.ptp_enabled
        self._link_settings, transport = sim_transport(s, self.path_mtu, warnings)
        if fmt != self._applied.get("PixelFormat"):
            self._prerendered = []  # rendered in the previous format
        self._renderer = renderer_for(self.world, self.size, pixel_formats.lookup(fmt).colour)
        self._applied = {"PixelFormat": fmt, "Width": w, "Height": h, "OffsetX": ox, "OffsetY": oy,
                         "ExposureTime": exposure, "Gain": gain_db, "AcquisitionFrameRate": rate,
                         "TriggerMode": "On" if s.trigger == "software" else "Off", **ptp, **transport}
        self._roi = (slice(oy, oy + h), slice(ox, ox + w))
        self._factor = exposure / NOMINAL_EXPOSURE_US * 10.0 ** (gain_db / 20.0)
        self._warnings = warnings
        for message in warnings:
            log.warning("sim camera %s: %s", self.serial, message)
        self.counters["applies"] += 1

    def _require_open(self) -> None:
        if self._lost:
            raise DeviceLost(f"sim camera {self.serial} is disconnected (disconnect_after="
                             f"{self.disconnect_after}); close() and open() again")
        if not self._open:
            raise DeviceError("camera is not open", code="not_open")

    # ------------------------------------------------------------------ frames

    def _render(self) -> np.ndarray:
        assert self._renderer is not None
        self.counters["renders"] += 1
        return sensor_image(self._renderer, self._applied["PixelFormat"], self.world.abs_H_cam(),
                            rng=self._rng, noise=self.noise)

    def _produce(self) -> Frame | None:
        """The next frame, or None when the drop knob eats it; raises DeviceLost on the disconnect knob."""
        self._require_open()
        if self.disconnect_after and self._frames_this_open >= self.disconnect_after:
            self._lost, self._streaming = True, False
            self.counters["disconnects"] += 1
            raise DeviceLost(f"sim camera {self.serial}: link lost after {self._frames_this_open} "
                             f"frames (disconnect_after={self.disconnect_after})")
        self._frame_id += 1
        self._frames_this_open += 1
        n = self._frame_id
        if self.drop_every and n % self.drop_every == 0:
            self.counters["dropped"] += 1
            return None
        start = self.clock.now_ns()  # the exposure starts: the pose is the one it sees
        pose = self.world.abs_H_cam()
        if self._prerendered:
            img = self._prerendered[(n - 1) % len(self._prerendered)]
        else:
            img = self._render()
        img = self._deliver(img[self._roi])
        exposure, device_ns = self._applied["ExposureTime"], self.clock.device_ns(start)
        extra: dict[str, Any] = {"sim": True, "sim_abs_H_cam": pose.tolist(),
                                 "sim_t_mid_ns": start + int(round(exposure * 500.0))}
        if self._applied.get("ChunkModeActive"):
            extra.update(chunk_timestamp_ns=device_ns, chunk_exposure_us=exposure,
                         chunk_gain_db=self._applied["Gain"])
        complete, wire_s = self.link.send(img.nbytes, self._link_settings)
        arrived = self.clock.arrival_ns(start, exposure, wire_s)
        if not complete or (self.incomplete_every and n % self.incomplete_every == 0):
            cut = int(self._cut_rng.integers(1, max(2, img.shape[0])))
            img[cut:] = 0  # the packets of the lower rows never arrived
            self.counters["incomplete"] += 1
            extra["incomplete"] = True
        self.counters["frames"] += 1
        return Frame(pixels=img, frame_id=n, camera_serial=self.serial,
                     pixel_format=self._applied["PixelFormat"], exposure_us=exposure,
                     device_time_ns=device_ns, host_time_ns=arrived,
                     host_monotonic_ns=arrived - (time.time_ns() - time.monotonic_ns()),
                     incomplete_count=self.counters["incomplete"], extra=extra,
                     transfer_ns=int(img.nbytes / self.link.rate(self._link_settings) * 1e9),
                     ptp=self.clock.ptp_status())

    def _deliver(self, img: np.ndarray) -> np.ndarray:
        """Exposure and gain, then the PixelFormat's wire layout and back: a copy the daemon owns."""
        fmt = self._applied["PixelFormat"]
        if self._factor != 1.0:
            peak = np.float32(2 ** pixel_formats.lookup(fmt).bits - 1)
            img = np.clip(img * np.float32(self._factor) + np.float32(0.5), 0, peak).astype(img.dtype)
        elif fmt == "Mono8":
            img = img.copy()  # prerendered images are shared
        if fmt == "Mono8":
            return img
        h, w = img.shape[:2]
        return pixel_formats.decode(pixel_formats.encode(img, fmt), fmt, w, h)

    def trigger(self, timeout: float = 5.0) -> Frame:
        """Render one frame at the robot's current pose."""
        frame = self._produce()
        if frame is None:
            raise DeviceTimeout(f"sim camera {self.serial}: triggered frame dropped "
                                f"(drop_every={self.drop_every}); no frame within {timeout:g} s")
        return frame

    def start_stream(self) -> None:
        self._require_open()
        self._want_stream = True
        if not self._streaming:
            self._streaming = True
            self._next_due = self.pacing.monotonic()

    def stop_stream(self) -> None:
        self._want_stream = False
        self._streaming = False

    def pump(self, timeout: float) -> None:
        """Emit the free-run frames that fall due within ``timeout`` s (a render may overrun)."""
        deadline = self.pacing.monotonic() + timeout
        if self._lost:
            self._require_open()
        while True:
            now = self.pacing.monotonic()
            if self._streaming and self._next_due <= now < deadline:
                period = 1.0 / self._applied["AcquisitionFrameRate"]
                # no catch-up bursts after a slow render: the next frame is due one period on
                self._next_due = max(self._next_due + period, now)
                frame = self._produce()
                if frame is not None:
                    self.emit("camera.frame", frame)
                self._publish_link(now)
                continue
            if now >= deadline:
                return
            wake = min(self._next_due, deadline) if self._streaming else deadline
            self.pacing.sleep(max(0.0, wake - now))

    def _publish_link(self, now: float) -> None:
        """``camera.link`` at most once a second, when a link counter changed (as the GenICam adapter)."""
        stats = self.link.stats()
        if now >= self._next_link and stats != self._last_link:
            self._next_link, self._last_link = now + 1.0, stats
            self.emit("camera.link", {"serial": self.serial, **stats})

    # ------------------------------------------------------------------ reporting

    def info(self) -> dict[str, Any]:
        return {"url": self.url.raw, "model": "SimCamera", "serial_number": self.serial,
                "size": list(self.size), "sim": True, "pixel_formats": list(PIXEL_FORMATS)}

    def status(self) -> dict[str, Any]:
        return {
            "open": self._open,
            "lost": self._lost,
            "streaming": self._streaming,
            "software_trigger": True,
            "serial": self.serial,
            "size": list(self.size),
            "settings": asdict(desired(self.settings)),
            "applied": dict(self._applied),
            "warnings": list(self._warnings),
            "incomplete_count": self.counters["incomplete"],
            "link": self.link.stats(),
            "ptp": self.clock.ptp_status(),
            "device_link_speed": self.link.link_bytes_s,  # the link model's, in SFNC's bytes/s
            **self.counters,
        }
