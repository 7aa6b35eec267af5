"""What ends a recording before it can hurt the robot: the free-space floor and ``--max-size``.

On the robot the recordings share a disk with the datasets: a recording of full frames at the
camera's rate writes hundreds of MB a second, and one that filled the disk took the datasets'
room with it. So before every message the recorder asks :meth:`Limits.reason` whether writing it
would take the file past ``--max-size`` or the disk's free space under ``--min-free``; when it
would, the recording ends there like a ``--duration`` does (the summary written, a valid file).
"""
from __future__ import annotations

import os
import re
import time
from pathlib import Path
from typing import Callable

from daemon.ctl.exitcodes import CtlError, Exit

#: the default floor: room for the datasets and the recorder's own summary, on the robot's disk
DEFAULT_MIN_FREE = 2_000_000_000
#: free space is probed again after this many bytes written or this many seconds, whichever first:
#: statvfs per message would cost more than the message at the tracker's rate, and 16 MB is far
#: below any sensible floor
PROBE_BYTES = 16_000_000
PROBE_S = 0.5
#: kept back for what the writer still adds: the chunk it buffers (1 MiB) and the summary
RESERVE = 4_000_000
#: a --max-size below this would end every recording at its first frame
MIN_MAX_SIZE = 10_000_000
_UNITS = {"": 1, "K": 10**3, "M": 10**6, "G": 10**9, "T": 10**12}


def parse_size(text: str, option: str) -> int:
    """``"500M"``, ``"2G"``, ``"1.5G"`` or bytes → bytes (decimal units, as the progress line's MB)."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d*)?)\s*([KMGT]?)B?\s*", text, re.IGNORECASE)
    if m is None:
        raise CtlError(Exit.USAGE, "usage", f"{option} must be a size such as 500M or 2G, got {text!r}")
    return int(float(m.group(1)) * _UNITS[m.group(2).upper()])


def free_bytes(folder: Path) -> int:
    """The space an unprivileged writer may still use in ``folder``'s file system."""
    st = os.statvfs(folder)
    return st.f_bavail * st.f_frsize


class Limits:
    """The floor and the size cap for one recording; ``free`` is the probe (tests pass their own)."""

    def __init__(self, folder: Path, min_free: int = DEFAULT_MIN_FREE, max_size: int | None = None,
                 free: Callable[[Path], int] = free_bytes) -> None:
        self.folder, self.min_free, self.max_size, self.free = folder, min_free, max_size, free
        self._probed_size = 0
        self._probed_t = float("-inf")
        self._free = 0

    @classmethod
    def from_options(cls, folder: Path, min_free: str | None, max_size: str | None) -> "Limits":
        """From ``--min-free`` and ``--max-size`` as typed (None: not given)."""
        floor = parse_size(min_free, "--min-free") if min_free is not None else DEFAULT_MIN_FREE
        cap = parse_size(max_size, "--max-size") if max_size is not None else None
        if cap is not None and cap < MIN_MAX_SIZE:
            raise CtlError(Exit.USAGE, "usage", f"--max-size must be at least {MIN_MAX_SIZE // 10**6}M, "
                                                f"got {max_size!r}")
        return cls(folder, floor, cap)

    def reason(self, size: int, incoming: int) -> str | None:
        """``"max_size"`` or ``"min_free"`` when ``incoming`` more bytes after ``size`` must not be
        written, else None."""
        if self.max_size is not None and size + incoming + RESERVE > self.max_size:
            return "max_size"
        now = time.monotonic()
        if size - self._probed_size >= PROBE_BYTES or now - self._probed_t >= PROBE_S:
            self._free, self._probed_size, self._probed_t = self.free(self.folder), size, now
        # between probes the free space shrinks by what this file grew (others' writes: the next probe)
        if self._free - (size - self._probed_size) - incoming - RESERVE < self.min_free:
            return "min_free"
        return None

    def describe(self, why: str) -> str:
        """Why the recording ended, for the operator."""
        if why == "max_size":
            return f"the file reached --max-size {(self.max_size or 0) / 1e6:.1f} MB"
        return (f"free space on {self.folder} fell to the floor (--min-free {self.min_free / 1e6:.1f} MB; "
                f"{self._free / 1e6:.1f} MB free at the last probe)")
