"""Device selection and pixel copying for the GenICam adapter (no harvesters objects needed).

Kept apart from :mod:`drivers.genicam` so they can be tested on plain data: the
producer's device list arrives as harvesters ``property_dict`` dictionaries and
image components only need ``width``, ``height``, ``num_components_per_pixel``
and a flat ``data`` array.
"""
from __future__ import annotations

from typing import Any

import numpy as np

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


def to_pixels(component: Any) -> np.ndarray:
    """Copy a 2-D image component out of its GenTL buffer as (h, w) or (h, w, c)."""
    h, w = int(component.height), int(component.width)
    c = max(1, int(round(component.num_components_per_pixel)))
    data = component.data
    row = w * c
    if data is None or data.size < h * row:
        raise DeviceError(f"camera buffer holds {0 if data is None else data.size} values, "
                          f"expected {h}x{w}x{c}", code="bad_buffer")
    # harvesters forgets to strip line padding, so cut rows ourselves when present
    flat = data[: h * row] if data.size % h else data.reshape(h, -1)[:, :row]
    return flat.reshape((h, w, c) if c > 1 else (h, w)).copy()
