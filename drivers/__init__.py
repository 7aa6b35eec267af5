"""Device drivers, each an adapter behind one small interface (drivers/base.py): the LUCID
camera over GenICam (harvesters), the AT901 tracker over emScon TCP, the robot base over a
serial line. Below the daemon: nothing here imports it.
"""
from __future__ import annotations

from importlib import import_module
from typing import Any

#: the package's public names -> the module that defines them; imported on first use, so a
#: laptop importing drivers.base never loads harvesters or pyserial
_FACE = {
    "Camera": "base", "CameraSettings": "base", "Device": "base", "DeviceError": "base", "DeviceLost": "base",
    "DeviceState": "base", "DeviceTimeout": "base", "DeviceURL": "base", "Frame": "base", "Robot": "base",
    "RobotState": "base", "Tracker": "base", "TrackerPoint": "base", "no_emit": "base",
    "EmsconTracker": "emscon.adapter", "GenICamCamera": "genicam", "SerialRobot": "robot",
}
__all__ = sorted(_FACE)


def __getattr__(name: str) -> Any:
    if name not in _FACE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{_FACE[name]}"), name)
