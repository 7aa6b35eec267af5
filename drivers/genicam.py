"""GenICam camera adapter over harvesters (LUCID Phoenix PHX122S through GenTL_LUCID.cti).

URL: ``genicam:///opt/ArenaSDK_Linux_x64/lib64/GenTL_LUCID.cti?serial=223600123``. The path is
the GenTL producer (.cti); the device is chosen by ``serial=``, by ``name=`` (the user-defined
name, DeviceUserID) or, as a last resort, by ``index=`` into the producer's device list; with none
of them the producer must offer exactly one device. Other options: ``num_buffers`` (GenTL buffers,
default 4, raised to the producer's minimum with a warning: harvesters refuses fewer; the settings'
``stream_buffers`` overrides it) and ``timeout`` (seconds without a frame
while streaming before the camera is declared lost, default 3; at least three frame periods).

Settings are applied at every ``open()`` by :mod:`drivers.genicam_settings`. Frames are decoded
from the raw GenTL buffer by :mod:`drivers.pixel_formats` and carry its name. ``trigger()`` fires
TriggerSoftware (after TriggerArmed where the device has it); on a device without software
triggers it takes the next free-run frame instead and says so in ``status()["warnings"]``.
``start_stream()`` switches to free run and ``pump()`` emits ``camera.frame``, and ``camera.link``
(``status()["link"]``) at most once a second when a link counter changed; ``status()["ptp"]``
reads the PTP state. Each frame is stamped on the host as its buffer arrives and carries, for the
daemon's clock (daemon/ritad/device_clock.py), its payload over the link rate (``transfer_ns``)
and the PTP state, read at most once a second. A missing device at ``open()`` and every transport
failure raise :class:`DeviceLost`, so the daemon's reconnect loop retries (a device whose GenTL access
status changes from the one it had at open counts as lost: :func:`drivers.genicam_device.access_lost`);
an ambiguous selection or bad settings raise :class:`DeviceError`.

harvesters allows one Harvester per producer per process and ``update()`` destroys live
acquirers, so each adapter owns its Harvester and ``close()`` resets it. Everything runs on the
caller's (the daemon runner's) thread: ``start(run_as_thread=True)`` would race our fetches.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

from harvesters.core import Harvester, ImageAcquirer

from drivers.base import Camera, DeviceError, DeviceLost, DeviceTimeout, DeviceURL, Emit, Frame, no_emit
from drivers.camera_settings import CameraSettings, desired
from drivers.genicam_device import access_lost, create_acquirer, read_held, select_device
from drivers.genicam_settings import SettingsWriter, find_node, set_trigger_mode
from drivers.genicam_transport import (GIGE_LINE_BYTES_S, IncompleteCounter, PtpWatch, apply_all, link_rate,
                                       link_stats, ptp_status, read_chunks)

log = logging.getLogger(__name__)

_STATUS_POLL_S = 1.0


class GenICamCamera(Camera):
    """A GenICam camera through harvesters; see the module docstring for the URL."""

    OPTIONS = frozenset({"serial", "name", "index", "num_buffers", "timeout"})

    def __init__(self, url: DeviceURL, *, emit: Emit = no_emit,
                 settings: CameraSettings | None = None) -> None:
        super().__init__(url, emit=emit, settings=settings)
        if not url.path.endswith(".cti"):
            raise ValueError(f"camera URL {url.raw!r} must name a GenTL producer .cti file, e.g. "
                             "genicam:///opt/ArenaSDK_Linux_x64/lib64/GenTL_LUCID.cti?serial=...")
        self.cti = url.path
        self.serial: str | None = url.option("serial", None)
        self.name: str | None = url.option("name", None)
        self.index: int | None = url.option("index", None, int)
        self.num_buffers: int = url.option("num_buffers", 4, int)
        self.timeout: float = url.option("timeout", 3.0, float)
        if self.index is not None and self.index < 0:
            raise ValueError(f"camera URL {url.raw!r}: index={self.index} must be >= 0")
        if self.num_buffers < 1:
            raise ValueError(f"camera URL {url.raw!r}: num_buffers={self.num_buffers} must be >= 1")
        if not (self.timeout > 0 and math.isfinite(self.timeout)):
            raise ValueError(f"camera URL {url.raw!r}: timeout={self.timeout} must be > 0")
        self._h: Harvester | None = None
        self._ia: ImageAcquirer | None = None
        self._incomplete = IncompleteCounter()
        self._facts: dict[str, Any] = {}
        self._logged: set[str] = set()
        self._software = False
        self._acquiring = False
        self._access = 0
        self._next_status_poll = 0.0
        self._last_frame = 0.0
        self._exposure: float | None = None
        self._link_rate, self._ptp = float(GIGE_LINE_BYTES_S), PtpWatch()
        self._last_link: dict[str, Any] = {}
        self.counters = {"opens": 0, "applies": 0, "writes": 0, "frames": 0, "timeouts": 0}

    # ------------------------------------------------------------------ lifecycle

    def open(self) -> None:
        """Load the producer, pick the device, apply the settings, arm the trigger."""
        if self._ia is not None:
            return
        if not Path(self.cti).is_file():
            raise DeviceError(f"GenTL producer {self.cti!r} not found (is the vendor SDK installed?)",
                              code="no_producer")
        try:
            self._h = Harvester()
            self._h.add_file(self.cti)
            self._h.update()
            infos = [d.property_dict for d in self._h.device_info_list]
            i = select_device(infos, self.serial, self.name, self.index)
            self._facts = {k: infos[i].get(k) for k in
                           ("serial_number", "model", "vendor", "user_defined_name", "id_", "tl_type")}
            self._ia = create_acquirer(self._h, i)  # its buffer count is set in _apply, above the minimum
            self._ia.add_callback(ImageAcquirer.Events.INCOMPLETE_BUFFER, self._incomplete)
            self._access = self._ia.device.module.access_status
            self._ptp = PtpWatch()  # a new connection: read the PTP state at the first frame
            self._apply()
            if self._software:
                self._start_acquisition()  # armed: trigger() only has to fire
            if self._want_stream:
                self.start_stream()
        except DeviceError:
            self.close()
            raise
        except Exception as exc:  # producer/transport failures: let the daemon retry
            self.close()
            raise DeviceLost(f"cannot open camera {self.url.raw!r}: {type(exc).__name__}: {exc}") from exc
        self.counters["opens"] += 1
        log.info("camera %s open (%s)", self._facts.get("serial_number"), self._facts.get("model"))

    def close(self) -> None:
        """Destroy the acquirer and reset the Harvester; never raises."""
        self._streaming = False
        self._acquiring = False
        ia, h, self._ia, self._h = self._ia, self._h, None, None
        if ia is not None:
            try:  # a lost device may throw AccessDenied/Busy here (harvesters #246)
                ia.destroy()
            except Exception as exc:
                log.warning("camera destroy failed: %s", exc)
        if h is not None:
            try:
                h.reset()
            except Exception as exc:
                log.warning("harvester reset failed: %s", exc)

    def _warn(self, message: str) -> None:
        if message not in self._logged:  # once per adapter, not at every reconnect
            self._logged.add(message)
            log.warning("camera %s: %s", self._facts.get("serial_number"), message)
        self._warnings.append(message)

    def _writer(self) -> SettingsWriter:
        assert self._ia is not None
        return SettingsWriter(self._ia.remote_device.node_map, self._warn, self._applied)

    def _stream_writer(self) -> SettingsWriter:
        assert self._ia is not None
        return SettingsWriter(self._ia.data_streams[0].node_map, self._warn, self._applied,
                              owner="the GenTL producer's stream")

    def _set_buffers(self, n: int) -> int:
        assert self._ia is not None
        self._ia.num_buffers = n  # allocated at the next start(); _apply runs while stopped
        return int(self._ia.num_buffers)

    def _apply(self) -> None:
        self._warnings = []
        self._applied = {}
        w = self._writer()
        minimum = getattr(self._ia, "min_num_buffers", 1)  # harvesters: STREAM_INFO_BUF_ANNOUNCE_MIN
        wanted = desired(self.settings)  # the URL's num_buffers unless the settings give stream_buffers
        if wanted.stream_buffers is None:
            wanted = replace(wanted, stream_buffers=self.num_buffers)
        self._software = apply_all(w, self._stream_writer(), wanted,
                                   self._set_buffers, int(minimum) if isinstance(minimum, int) else 1)
        exposure = w.read("ExposureTime")
        self._exposure = None if exposure is None else float(exposure)
        self._link_rate = link_rate(w)
        self.counters["applies"] += 1
        self.counters["writes"] += w.writes

    def _require_open(self) -> ImageAcquirer:
        if self._ia is None:
            raise DeviceError("camera is not open", code="not_open")
        return self._ia

    def _lost(self, what: str, exc: BaseException) -> DeviceLost:
        return DeviceLost(f"camera {self._facts.get('serial_number')!r} lost during {what}: "
                          f"{type(exc).__name__}: {exc}")

    def _start_acquisition(self) -> None:
        ia = self._require_open()
        if not self._acquiring:
            try:
                ia.start()
            except Exception as exc:
                raise self._lost("acquisition start", exc) from exc
            self._acquiring = True

    def _stop_acquisition(self) -> None:
        if self._ia is not None and self._acquiring:
            self._acquiring = False
            try:
                self._ia.stop()
            except Exception as exc:
                raise self._lost("acquisition stop", exc) from exc

    # ------------------------------------------------------------------ frames

    def _fetch(self, deadline: float) -> Frame | None:
        """The next complete frame before ``deadline`` (monotonic s), or None."""
        ia = self._require_open()
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            try:
                # try_fetch, not fetch: fetch restarts its timeout after every
                # incomplete buffer, so it may never return on a lossy link.
                buf = ia.try_fetch(timeout=max(remaining, 0.001), is_raw=True)
            except Exception as exc:
                raise self._lost("fetch", exc) from exc
            if buf is not None:
                break
        rx_ns, rx_mono = time.time_ns(), time.monotonic_ns()  # arrival, before any decoding delays it
        try:  # chunk nodes read the held buffer's memory: only valid before the requeue
            chunked = bool(self._applied.get("ChunkModeActive"))
            held = read_held(buf, (lambda: read_chunks(self._writer())) if chunked else None)
            ptp = self._ptp.poll(self._writer)
        except DeviceError:
            raise
        except Exception as exc:
            raise self._lost("buffer read", exc) from exc
        self.counters["frames"] += 1
        self._last_frame = time.monotonic()
        return Frame(pixels=held.pixels, frame_id=held.frame_id, pixel_format=held.pixel_format,
                     camera_serial=str(self._facts.get("serial_number")),
                     exposure_us=held.chunks.get("chunk_exposure_us", self._exposure),
                     device_time_ns=held.device_ns,
                     host_time_ns=rx_ns, host_monotonic_ns=rx_mono, incomplete_count=self._incomplete.count,
                     extra=held.chunks, transfer_ns=int(held.size * 1e9 / self._link_rate), ptp=ptp)

    def _check_access(self, force: bool = False) -> None:
        """Poll the device's access status (about once a second); a change means loss."""
        now = time.monotonic()
        if self._ia is None or (not force and now < self._next_status_poll):
            return
        self._next_status_poll = now + _STATUS_POLL_S
        try:
            status = self._ia.device.module.access_status
        except Exception as exc:
            raise self._lost("status poll", exc) from exc
        if access_lost(self._access, status):
            raise DeviceLost(f"camera {self._facts.get('serial_number')!r} access status changed "
                             f"from {self._access} to {status}")

    def _stall_limit(self) -> float:
        rate = self._applied.get("AcquisitionFrameRate")
        return max(self.timeout, 3.0 / float(rate)) if rate else self.timeout

    def _no_frame(self, what: str, timeout: float) -> DeviceTimeout:
        self.counters["timeouts"] += 1
        self._check_access(force=True)
        return DeviceTimeout(f"camera {self._facts.get('serial_number')!r}: no frame within "
                             f"{timeout:g} s of {what}")

    def trigger(self, timeout: float = 5.0) -> Frame:
        """One frame taken after this call (software trigger, or next free-run frame)."""
        ia = self._require_open()
        deadline = time.monotonic() + timeout
        if self._streaming:
            frame = self._fetch(deadline)
            if frame is None:
                raise self._no_frame("trigger (streaming)", timeout)
            return frame
        if not self._software:
            # No trigger on this device: start, take the first frame, stop again, so
            # the frame is never a stale one left in the buffers.
            self._start_acquisition()
            try:
                frame = self._fetch(deadline)
            finally:
                self._stop_acquisition()
            if frame is None:
                raise self._no_frame("acquisition start", timeout)
            return frame
        self._start_acquisition()
        for _ in range(int(ia.num_buffers) + 1):  # drop frames left by an earlier timed-out trigger
            if self._fetch(time.monotonic() + 0.001) is None:
                break
        nm = ia.remote_device.node_map
        armed = find_node(nm, "TriggerArmed")
        try:
            while armed is not None and not armed.value:
                if time.monotonic() > deadline:
                    raise self._no_frame("waiting for TriggerArmed", timeout)
                time.sleep(0.001)
            self._writer().execute("TriggerSoftware")
        except DeviceError:
            raise
        except Exception as exc:
            raise self._lost("software trigger", exc) from exc
        frame = self._fetch(deadline)
        if frame is None:
            raise self._no_frame("TriggerSoftware", timeout)
        return frame

    def start_stream(self) -> None:
        """Free run; ``pump`` emits every frame as ``camera.frame``."""
        self._require_open()
        self._want_stream = True
        if self._streaming:
            return
        if self._software:
            self._stop_acquisition()  # many cameras refuse TriggerMode writes while acquiring
            self._set_software(False)
        self._start_acquisition()
        self._streaming = True
        self._last_frame = time.monotonic()

    def stop_stream(self) -> None:
        """Leave free run; re-arm the software trigger when the device has one."""
        self._want_stream = False
        if not self._streaming or self._ia is None:
            self._streaming = False
            return
        self._streaming = False
        self._stop_acquisition()
        if self._software:
            self._set_software(True)
            self._start_acquisition()

    def _set_software(self, on: bool) -> None:
        try:
            set_trigger_mode(self._writer(), on)
        except DeviceError:
            raise
        except Exception as exc:
            raise self._lost("trigger mode change", exc) from exc

    def pump(self, timeout: float) -> None:
        """Emit the frames that arrive within ``timeout`` s; detect a stalled stream."""
        deadline = time.monotonic() + timeout
        if self._ia is None or not self._streaming:
            if self._ia is not None:
                self._check_access()
            time.sleep(max(0.0, deadline - time.monotonic()))
            return
        while True:
            frame = self._fetch(deadline)
            if frame is None:
                break
            self.emit("camera.frame", frame)
        if time.monotonic() >= self._next_status_poll:  # the same once-a-second pace as the access poll
            self._publish_link()
        self._check_access()
        stalled = time.monotonic() - self._last_frame
        if stalled > self._stall_limit():
            raise DeviceLost(f"camera {self._facts.get('serial_number')!r}: no frame for "
                             f"{stalled:.1f} s while streaming")

    # ------------------------------------------------------------------ reporting

    def info(self) -> dict[str, Any]:
        return {"url": self.url.raw, "producer": self.cti, **self._facts}

    def _link(self) -> dict[str, Any]:
        return link_stats(self._stream_writer(), {"incomplete_frames": self._incomplete.count})

    def _publish_link(self) -> None:
        link = self._link()
        if link != self._last_link and self._last_link:  # the first reading is the baseline
            self.emit("camera.link", {"serial": self._facts.get("serial_number"), **link})
        self._last_link = link

    def status(self) -> dict[str, Any]:
        opened = self._ia is not None
        return {
            "open": opened, "streaming": self._streaming, "acquiring": self._acquiring,
            "software_trigger": self._software, "serial": self._facts.get("serial_number"),
            "settings": asdict(desired(self.settings)),
            "applied": dict(self._applied), "warnings": list(self._warnings),
            "incomplete_count": self._incomplete.count, "link": self._link() if opened else None,
            "ptp": ptp_status(self._writer()) if opened else {"available": False},
            # as the camera gives it (SFNC: bytes/s), for ritactl commission; None without the node
            "device_link_speed": self._writer().read("DeviceLinkSpeed") if opened else None,
            **self.counters,
        }
