"""The simulated camera's ray residuals kept on disk between processes (fakes/render.py computes them).

Every simulated ritad opens its camera with the same lens and image size, and each one computed the
same residuals again (``cv2.undistortPoints`` over every sub-sample node: seconds of CPU per ritad
start). They depend only on what the key holds (the lens, the size, the sub-sample grid, the
undistortion's criteria, the source of the function computing them, the OpenCV and numpy versions),
so a file written once serves every later process: the arrays loaded are the bytes computed
(tests/fakes/test_render.py). Writes are atomic (daemon/bus/storage.py ``atomic_write_bytes``); a
missing, unreadable or malformed file is computed again, a folder that cannot be written is passed
over. Where: ``$RITA_SIM_CACHE``, else ``~/.cache/rita-sim``; only grids of :data:`MIN_NODES` or more are kept
(smaller ones compute in well under a second).
"""
from __future__ import annotations

import hashlib
import io
import os
from pathlib import Path

import cv2
import numpy as np

from daemon.bus.storage import atomic_write_bytes

#: smallest node grid worth a file (the reduced camera's grid is ~6.8 M nodes, 54 MB)
MIN_NODES = 1_000_000


def cache_dir() -> Path:
    return Path(os.environ.get("RITA_SIM_CACHE") or Path.home() / ".cache" / "rita-sim")


def file_name(parts: tuple[object, ...]) -> str:
    """The file of one key: a hash of its parts and of the library versions that compute them."""
    h = hashlib.sha256(repr((cv2.__version__, np.__version__)).encode())
    for part in parts:
        h.update(part if isinstance(part, bytes) else repr(part).encode())
        h.update(b"\0")  # parts stay apart: ("ab", "c") is not ("a", "bc")
    return f"rays-{h.hexdigest()[:40]}.npy"


def load(name: str, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """(dx, dy) read-only from the file ``name``, or None when absent or not two float32 ``shape`` grids."""
    try:
        both = np.load(cache_dir() / name, allow_pickle=False)
    except (OSError, ValueError, EOFError):
        return None
    if both.dtype != np.float32 or both.shape != (2, *shape):
        return None
    both.flags.writeable = False  # shared between renderers, as the computed ones
    return both[0], both[1]


def store(name: str, dx: np.ndarray, dy: np.ndarray) -> None:
    """Write (dx, dy) as the file ``name`` with the project's atomic write (whole or not at all: a concurrent
    reader never sees half a file); a folder that cannot be written is passed over."""
    buf = io.BytesIO()
    np.save(buf, np.stack([dx, dy]), allow_pickle=False)
    try:
        atomic_write_bytes(cache_dir() / name, buf.getbuffer())
    except OSError:
        pass  # a read-only home or a full disk: the next process computes them again
