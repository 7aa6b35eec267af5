"""Read-only access to the data dir over the bus (``files.list`` / ``files.read`` / ``files.hash``).

The robot keeps its datasets, reports and results 0600 in ``data_dir`` and the bus is
the laptop's only channel, so ``ritactl fetch`` copies them through these commands.
Every path is relative to ``data_dir`` and confined to it: absolute paths, ``..``
and symlinks that resolve outside are refused, and secrets (the CURVE key folders,
``*.key_secret``) are never listed or read. Reads are chunked (``CHUNK_MAX``) so a
reply never holds a whole multi-megabyte image.
"""
from __future__ import annotations

import hashlib
import os
import re
from pathlib import Path, PurePosixPath
from typing import Any

from daemon.bus.protocol import CommandError, ErrorCode

CHUNK_MAX = 1 << 20  # bytes per files.read reply
LIST_MAX = 20000  # entries per files.list reply; more is reported as truncated
#: top-level folders never served: the daemon's CURVE keys and the allow-list
PRIVATE_DIRS = ("keys", "authorized_keys")
_DRIVE = re.compile(r"^[A-Za-z]:")


def _refuse(cmd: str, path: str, why: str) -> CommandError:
    return CommandError(ErrorCode.BAD_ARGS, f"{cmd}: path {path!r} {why}")


def _unreadable(cmd: str, path: str, exc: OSError) -> CommandError:
    return CommandError(ErrorCode.NOT_FOUND, f"{cmd}: cannot read {path!r}: {exc.strerror or exc}")


def _private(rel: PurePosixPath, private: tuple[str, ...]) -> bool:
    return bool(rel.parts) and (rel.parts[0] in private or rel.name.endswith(".key_secret"))


def confine(root: Path, path: str, cmd: str, private: tuple[str, ...] = PRIVATE_DIRS) -> Path:
    """``root/path`` resolved, or ``bad_args`` if it is absolute, climbs out, or names a secret."""
    if "\x00" in path or "\\" in path:
        raise _refuse(cmd, path, "contains a NUL or a backslash (use '/')")
    rel = PurePosixPath(path)
    if rel.is_absolute() or _DRIVE.match(path):
        raise _refuse(cmd, path, "is absolute: give it relative to the data dir")
    if ".." in rel.parts:
        raise _refuse(cmd, path, "contains '..': paths stay inside the data dir")
    if _private(rel, private):
        raise _refuse(cmd, path, "is private to the robot (keys are never served)")
    root = root.resolve()
    try:
        target = (root / rel).resolve()
        exists = target.exists()
    except (OSError, RuntimeError, ValueError) as exc:  # a name too long, a symlink loop (RuntimeError), ...
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise _refuse(cmd, path, f"cannot be resolved ({why})") from None
    if target != root and not target.is_relative_to(root):
        raise _refuse(cmd, path, "leads outside the data dir (symlink)")
    if not exists:
        raise CommandError(ErrorCode.NOT_FOUND, f"{cmd}: no file {path!r} in the data dir")
    return target


def _walk(root: Path, start: Path) -> list[Path]:
    """Regular files under ``start``; symlinked folders are not followed (no loops, no escapes)."""
    if start.is_file():
        return [start]
    out = []
    for dirpath, dirnames, filenames in os.walk(start):
        dirnames.sort()
        for name in sorted(filenames):
            out.append(Path(dirpath) / name)
    return out


def list_files(root: Path, path: str = "", private: tuple[str, ...] = PRIVATE_DIRS) -> dict[str, Any]:
    """``{root, files: [{path, size, mtime_ns}], truncated}`` for every servable file under ``path``."""
    root = root.resolve()
    start = confine(root, path, "files.list", private) if path else root
    files: list[dict[str, Any]] = []
    truncated = False
    for p in _walk(root, start):
        rel = PurePosixPath(p.relative_to(root).as_posix())
        if _private(rel, private) or (rel.name.startswith(".") and rel.name.endswith(".tmp")):
            continue  # secrets, and half-written files of an atomic write in progress
        try:
            real = p.resolve()
            if not real.is_relative_to(root) or not real.is_file():
                continue  # a symlink to outside the data dir, or to nothing
            st = real.stat()
        except (OSError, RuntimeError):
            continue  # removed while we walked, or a symlink loop
        if len(files) >= LIST_MAX:
            truncated = True
            break
        files.append({"path": str(rel), "size": st.st_size, "mtime_ns": st.st_mtime_ns})
    return {"root": str(root), "files": files, "truncated": truncated}


def read_chunk(root: Path, path: str, offset: int, length: int,
               private: tuple[str, ...] = PRIVATE_DIRS) -> tuple[dict[str, Any], bytes]:
    """Bytes ``[offset, offset + length)`` of a file (fewer at its end) and ``{size, mtime_ns, eof}``."""
    if offset < 0:
        raise CommandError(ErrorCode.BAD_ARGS, f"files.read: offset={offset} must be >= 0")
    if not 0 < length <= CHUNK_MAX:
        raise CommandError(ErrorCode.BAD_ARGS, f"files.read: length={length} must be in (0, {CHUNK_MAX}]")
    target = confine(root, path, "files.read", private)
    if not target.is_file():
        raise CommandError(ErrorCode.BAD_ARGS, f"files.read: {path!r} is not a file")
    try:
        with open(target, "rb") as f:
            st = os.fstat(f.fileno())
            f.seek(offset)
            data = f.read(length)
    except OSError as exc:  # vanished or unreadable since confine(): an answer, not a crash
        raise _unreadable("files.read", path, exc) from None
    meta = {"path": path, "offset": offset, "length": len(data), "size": st.st_size,
            "mtime_ns": st.st_mtime_ns, "eof": offset + len(data) >= st.st_size}
    return meta, data


def hash_file(root: Path, path: str, length: int | None = None,
              private: tuple[str, ...] = PRIVATE_DIRS) -> dict[str, Any]:
    """sha256 of the first ``length`` bytes (the whole file when None): resume and verify checks."""
    if length is not None and length < 0:
        raise CommandError(ErrorCode.BAD_ARGS, f"files.hash: length={length} must be >= 0")
    target = confine(root, path, "files.hash", private)
    if not target.is_file():
        raise CommandError(ErrorCode.BAD_ARGS, f"files.hash: {path!r} is not a file")
    h = hashlib.sha256()
    try:
        with open(target, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            left = size if length is None else min(length, size)
            n = left
            while left > 0:
                block = f.read(min(left, CHUNK_MAX))
                if not block:
                    break
                h.update(block)
                left -= len(block)
    except OSError as exc:
        raise _unreadable("files.hash", path, exc) from None
    return {"path": path, "length": n - left, "size": size, "sha256": h.hexdigest()}
