"""One ritad per runtime directory: an flock taken before anything binds.

libzmq unlinks an existing ipc socket file when it binds the same path, so a second
ritad started on the same config would silently take the first one's ipc endpoints
(and remove them again when it fails on the tcp port). ritad therefore locks
``ritad.lock`` in every directory that holds one of its ipc endpoints, and in its
data directory, before it creates any socket. The lock file keeps the holder's pid
so the refusal can name it. The kernel drops the lock when the process dies, so a
SIGKILLed ritad never leaves a stale lock behind; the lock file itself stays.
"""
from __future__ import annotations

import errno
import fcntl
import os
import stat
from pathlib import Path

from daemon.ritad.config import Config

LOCK_NAME = "ritad.lock"


class AlreadyRunning(Exception):
    """Another process holds the lock of one of our directories."""


def ipc_paths(endpoints: list[str]) -> list[Path]:
    """File system paths of the ``ipc://`` endpoints (abstract ``ipc://@name`` has none)."""
    return [Path(e[len("ipc://"):]) for e in endpoints
            if e.startswith("ipc://") and not e.startswith("ipc://@")]


def lock_dirs(cfg: Config) -> list[Path]:
    """Every directory holding one of the daemon's ipc endpoints, then the data directory."""
    d = cfg.daemon
    dirs = sorted({p.parent.resolve() for p in ipc_paths(d.command_endpoints + d.telemetry_endpoints +
                                                          d.frame_endpoints)})
    data = Path(d.data_dir).resolve()
    return dirs + ([data] if data not in dirs else [])


def _holder(path: Path) -> str:
    try:
        pid = path.read_text().strip()
    except OSError:
        pid = ""
    return f"pid {pid}" if pid.isdigit() else "another process"


class InstanceLock:
    """Hold ``ritad.lock`` in each directory for the life of the process (``release()`` at stop)."""

    def __init__(self, dirs: list[Path]) -> None:
        self.dirs = dirs
        self._fds: list[int] = []

    def acquire(self) -> None:
        """Lock every directory or none; raises AlreadyRunning naming the holder's pid."""
        try:
            for directory in self.dirs:
                directory.mkdir(parents=True, exist_ok=True)
                path = directory / LOCK_NAME
                fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o640)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError as exc:
                    os.close(fd)
                    if exc.errno not in (errno.EWOULDBLOCK, errno.EACCES):
                        raise
                    raise AlreadyRunning(f"another ritad ({_holder(path)}) already runs in {directory} "
                                         f"(lock {path}); stop it first, or give this one other ipc "
                                         f"endpoints and another data_dir") from None
                self._fds.append(fd)
                os.ftruncate(fd, 0)  # only now: the pid in the file is always the holder's
                os.write(fd, f"{os.getpid()}\n".encode())
        except BaseException:
            self.release()
            raise

    def release(self) -> None:
        for fd in self._fds:
            os.close(fd)  # closing the descriptor drops the flock
        self._fds = []


def remove_socket_files(endpoints: list[str]) -> list[Path]:
    """Unlink the ipc socket files of ``endpoints`` (libzmq leaves them behind); returns those removed."""
    removed = []
    for path in ipc_paths(endpoints):
        try:
            if stat.S_ISSOCK(path.lstat().st_mode):
                path.unlink()
                removed.append(path)
        except FileNotFoundError:
            pass
    return removed
