"""Device selection and pixel decoding for the GenICam adapter (no harvesters objects needed).

Kept apart from :mod:`drivers.genicam` so they can be tested on plain data: the
producer's device list arrives as harvesters ``property_dict`` dictionaries; a raw
GenTL buffer only needs ``pixel_format`` (PFNC code), ``width``, ``height``,
``padding_x``, ``image_offset``, ``size_filled`` and ``raw_buffer`` (bytes).
"""
from __future__ import annotations

import signal
import threading
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from genicam import gentl
from harvesters.core import Harvester, ImageAcquirer

from drivers import pixel_formats
from drivers.base import DeviceError, DeviceLost


def describe(info: dict[str, Any]) -> str:
    """One device of the producer's list, as shown in selection errors."""
    return (f"serial={info.get('serial_number')!r} model={info.get('model')!r} "
            f"name={info.get('user_defined_name')!r} id={info.get('id_')!r}")


def select_device(infos: list[dict[str, Any]], serial: str | None, name: str | None,
                  index: int | None) -> int:
    """Index of the one device matching the selection (property dicts filtered here)."""
    found = "; ".join(describe(i) for i in infos) or "none"
    if index is not None:
        if not 0 <= index < len(infos):
            raise DeviceLost(f"camera index={index} does not exist ({len(infos)} found: {found})",
                             code="no_device")
        return index
    if serial is None and name is None:
        if len(infos) == 1:
            return 0
        if not infos:
            raise DeviceLost("the GenTL producer found no camera", code="no_device")
        raise DeviceError(f"{len(infos)} cameras found; choose one with serial= or name= ({found})",
                          code="ambiguous_device")
    hits = [i for i, d in enumerate(infos)
            if (serial is None or str(d.get("serial_number")) == serial)
            and (name is None or d.get("user_defined_name") == name)]
    want = " ".join(f"{k}={v!r}" for k, v in (("serial", serial), ("name", name)) if v is not None)
    if not hits:
        raise DeviceLost(f"no camera with {want} (found: {found})", code="no_device")
    if len(hits) > 1:
        raise DeviceError(f"{len(hits)} cameras match {want} (found: {found})", code="ambiguous_device")
    return hits[0]


def _info(buf: Any, name: str, default: int | None = None) -> int:
    """An integer buffer info; producers that cannot report padding or offset mean 0."""
    try:
        return int(getattr(buf, name))
    except Exception:  # genicam.gentl exceptions: NotAvailable, NotImplemented, ...
        if default is None:
            raise
        return default


def decode_buffer(buf: Any) -> tuple[np.ndarray, str]:
    """(pixels, PFNC name) of a raw GenTL buffer, decoded by :mod:`drivers.pixel_formats` (a copy).

    harvesters' own component decoding is bypassed: it keeps line padding
    and unpacks 12-bit formats slowly. An unsupported format or a buffer
    shorter than its image raises DeviceError code ``bad_buffer`` naming both.
    """
    try:
        fmt = pixel_formats.by_code(_info(buf, "pixel_format"))
        w, h = _info(buf, "width"), _info(buf, "height")
        pad, offset = _info(buf, "padding_x", 0), _info(buf, "image_offset", 0)
        raw = buf.raw_buffer
        filled = _info(buf, "size_filled", len(raw))
        return pixel_formats.decode(memoryview(raw)[:max(filled, 0)], fmt.name, w, h, pad, offset), fmt.name
    except ValueError as exc:
        raise DeviceError(f"camera buffer: {exc}", code="bad_buffer") from None


def payload_bytes(buf: Any) -> int:
    """The bytes a raw GenTL buffer received (its ``size_filled``, else its length)."""
    return _info(buf, "size_filled", len(buf.raw_buffer))


def create_acquirer(h: Harvester, i: int) -> ImageAcquirer:
    """``h.create(i)`` without letting harvesters keep its own SIGINT handler.

    harvesters installs one when created on the main thread (Ctrl-C would then destroy the
    acquirer instead of stopping the program).
    """
    on_main = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGINT) if on_main else None
    try:
        return h.create(i)
    finally:
        if on_main and previous is not None:
            signal.signal(signal.SIGINT, previous)


@dataclass
class HeldBuffer:
    """What is read from a fetched buffer before it goes back to the producer."""

    pixels: np.ndarray
    pixel_format: str
    frame_id: int
    size: int
    chunks: dict[str, Any]
    device_ns: int | None


def read_held(buf: Any, chunks: Callable[[], dict[str, Any]] | None) -> HeldBuffer:
    """Pixels (a copy), ids, chunk values (read while the buffer is held) and the device time, then requeue.

    The device time is the buffer's ``timestamp_ns``; a producer without one (harvesters raises, or
    it reads 0) leaves the ``Timestamp`` chunk as the time (the same device clock, PTP time when locked).
    """
    try:
        pixels, fmt = decode_buffer(buf)
        frame_id, size = int(buf.frame_id), payload_bytes(buf)
        values = chunks() if chunks is not None else {}
        try:
            device_ns: int | None = int(buf.timestamp_ns) or None
        except (gentl.GenericException, AttributeError):
            device_ns = None  # viky and some producers have no buffer timestamps
        if device_ns is None and values.get("chunk_timestamp_ns"):
            device_ns = int(values["chunk_timestamp_ns"])
    finally:
        buf.parent.queue_buffer(buf)
    return HeldBuffer(pixels, fmt, frame_id, size, values, device_ns)


def access_lost(at_open: int, now: int) -> bool:
    """Whether a device's GenTL access status says it is gone: a change from the value it had at open.

    The values differ by producer and GenTL version: BUSY (4), OPEN_READWRITE (5) and OPEN_READONLY (6)
    exist since GenTL 1.5 (GenTL.h v1.6 as published in AravisProject/aravis src/gentl/GenTL_v1_6.h,
    DEVICE_ACCESS_STATUS_LIST); an older producer may report READWRITE (1) or UNKNOWN (0) for an open
    device, and custom values start at 1000. So only a change is news, not a particular value.
    """
    return int(now) != int(at_open)
