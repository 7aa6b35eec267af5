"""A GenTL producer and acquirer shaped like harvesters' objects, for the GenICam adapter's open path.

``drivers.genicam`` drives harvesters (``Harvester``, ``ImageAcquirer``, buffers); harvesters needs a
real ``.cti``. This stand-in offers the same surface the adapter uses, over :mod:`fakes.genicam_nodes`'
node maps, so the producer's documented variations can be switched on per test:

* ``buffer_minimum``: the producer's STREAM_INFO_BUF_ANNOUNCE_MIN. harvesters' ``num_buffers`` setter
  raises ``ValueError`` below it ("The number of buffers must be greater than or equal to ...",
  harvesters/core.py, ImageAcquirer.num_buffers), and so does this one. LUCID's own minimum is not
  public; 8 is a value that breaks a count of 4.
* ``access_status``: the GenTL DEVICE_ACCESS_STATUS an open device reports. GenTL 1.5 added BUSY (4),
  OPEN_READWRITE (5) and OPEN_READONLY (6) (GenTL.h v1.6, AravisProject/aravis src/gentl/GenTL_v1_6.h);
  a producer of an earlier convention reports READWRITE (1) for a device it has open. ``lose()``
  makes the device unreachable: NOACCESS (3).
* ``buffer_timestamps``: False for a producer whose buffers carry no timestamp (harvesters raises a
  GenTL exception on ``timestamp_ns``); the camera's ``Timestamp`` chunk still has the time.
* AcquisitionMode (SFNC): ``SingleFrame`` delivers one frame per start; ``Continuous`` (and, here,
  ``MultiFrame``) until stopped.

Frames are Mono8 ramps of ``size`` (width, height), one every ``frame_period_s`` of the caller's clock.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from genicam import gentl

from fakes.genicam_nodes import FakeNodeMap, camera_node_map, stream_node_map

MONO8 = 0x01080001  # PFNC Mono8
OPEN_READWRITE, READWRITE, NOACCESS = 5, 1, 3


@dataclass
class ProducerSpec:
    """The producer's and camera's behaviours (module docstring)."""

    buffer_minimum: int = 2
    access_status: int = OPEN_READWRITE
    buffer_timestamps: bool = True
    size: tuple[int, int] = (32, 24)
    frame_period_s: float = 0.01
    serial: str = "PHX-FAKE-1"
    camera: dict[str, Any] = field(default_factory=dict)  # camera_node_map keyword arguments


class _Buffer:
    def __init__(self, parent: "_Stream", frame_id: int, data: bytes, w: int, h: int,
                 stamp: int | None) -> None:
        self.parent, self.frame_id, self.raw_buffer = parent, frame_id, data
        self.pixel_format, self.width, self.height = MONO8, w, h
        self.padding_x, self.image_offset, self.size_filled = 0, 0, len(data)
        self._stamp = stamp

    @property
    def timestamp_ns(self) -> int:
        if self._stamp is None:
            raise gentl.NotAvailableException("buffer has no timestamp")
        return self._stamp


class _Stream:
    def __init__(self, node_map: FakeNodeMap) -> None:
        self.node_map = node_map
        self.queued = 0

    def queue_buffer(self, buf: _Buffer) -> None:
        self.queued += 1


class _Module:
    def __init__(self, status: int) -> None:
        self.access_status = status


class _Device:
    def __init__(self, status: int) -> None:
        self.module = _Module(status)


class _Remote:
    def __init__(self, node_map: FakeNodeMap) -> None:
        self.node_map = node_map


class FakeAcquirer:
    """The parts of harvesters' ImageAcquirer the GenICam adapter uses."""

    def __init__(self, spec: ProducerSpec) -> None:
        self.spec = spec
        self.remote_device = _Remote(camera_node_map(**spec.camera))
        self.data_streams = [_Stream(stream_node_map(buffer_minimum=spec.buffer_minimum))]
        self.device = _Device(spec.access_status)
        self.min_num_buffers = spec.buffer_minimum
        self._num_buffers = max(3, spec.buffer_minimum)  # harvesters' default
        self.acquiring, self.started, self.destroyed = False, 0, False
        self._frame_id, self._left, self._next = 0, -1, 0.0

    @property
    def num_buffers(self) -> int:
        return self._num_buffers

    @num_buffers.setter
    def num_buffers(self, value: int) -> None:
        if value < self.min_num_buffers:
            raise ValueError(f"The number of buffers must be greater than or equal to {self.min_num_buffers}")
        self._num_buffers = value

    def add_callback(self, event: Any, callback: Any) -> None:
        pass

    def start(self) -> None:
        nm = self.remote_device.node_map
        mode = nm["AcquisitionMode"]
        self._left = 1 if mode == "SingleFrame" else -1
        self.acquiring, self.started, self._next = True, self.started + 1, time.monotonic()

    def stop(self) -> None:
        self.acquiring = False

    def destroy(self) -> None:
        self.acquiring, self.destroyed = False, True

    def lose(self) -> None:
        """The camera is unplugged: the producer reports it unreachable."""
        self.device.module.access_status = NOACCESS

    def try_fetch(self, timeout: float, is_raw: bool = True) -> _Buffer | None:
        end = time.monotonic() + timeout
        while not (self.acquiring and self._left != 0 and time.monotonic() >= self._next):
            if time.monotonic() >= end:
                return None
            time.sleep(min(0.002, max(0.0, end - time.monotonic())))
        self._next += self.spec.frame_period_s
        self._left -= 1 if self._left > 0 else 0
        self._frame_id += 1
        w, h = self.spec.size
        data = bytes((i + self._frame_id) % 256 for i in range(w * h))
        stamp = time.time_ns() if self.spec.buffer_timestamps else None
        return _Buffer(self.data_streams[0], self._frame_id, data, w, h, stamp)


class _Info:
    def __init__(self, spec: ProducerSpec) -> None:
        self.property_dict = {"serial_number": spec.serial, "model": "PHX122S-fake", "vendor": "fake",
                              "user_defined_name": None, "id_": spec.serial, "tl_type": "GEV"}


class FakeHarvester:
    """The parts of harvesters' Harvester the adapter uses; ``spec`` describes the next one's device."""

    spec = ProducerSpec()
    made: list[FakeAcquirer] = []

    def __init__(self) -> None:
        self.device_info_list: list[_Info] = []

    def add_file(self, path: str) -> None:
        pass

    def update(self) -> None:
        self.device_info_list = [_Info(self.spec)]

    def create(self, i: int) -> FakeAcquirer:
        ia = FakeAcquirer(self.spec)
        FakeHarvester.made.append(ia)
        return ia

    def reset(self) -> None:
        self.device_info_list = []
