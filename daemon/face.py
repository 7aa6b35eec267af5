"""A package's face: its public names, imported from their modules on first use (PEP 562).

``__all__, __getattr__ = lazy_face(__name__, {"Client": "client", ...})`` in a package's
``__init__``: ``from daemon.bus import Client`` works and documents the public names, while
importing one submodule never loads the others (ritactl stays free of numpy and OpenCV).
"""
from __future__ import annotations

from importlib import import_module
from typing import Any, Callable


def lazy_face(package: str, face: dict[str, str]) -> tuple[list[str], Callable[[str], Any]]:
    """``(__all__, __getattr__)`` for ``package`` whose public ``name`` lives in ``package.face[name]``."""
    def getattr_(name: str) -> Any:
        if name not in face:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(import_module(f"{package}.{face[name]}"), name)

    return sorted(face), getattr_


__all__ = ["lazy_face"]
