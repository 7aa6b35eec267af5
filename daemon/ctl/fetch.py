"""``ritactl fetch``: copy datasets, reports, plots and results from the robot's data dir to here.

Without a PATH it takes ``DEFAULT_PATHS`` only, never the daemon's housekeeping files (its lock,
the stop latch, the worker's log); ``--quiet`` prints the summary line alone.

The files are 0600 on the robot and the bus is the only channel, so this pulls them
with ``files.list`` / ``files.read`` / ``files.hash`` (docs/protocol.md), in chunks.
Each file goes to a hidden ``.NAME.part`` next to its target, is fsynced, checked
against the robot's sha256 and renamed into place, so an interrupted fetch never
leaves a half file under the real name. (Not daemon/bus/storage.py's atomic_write_bytes:
the ``.part`` keeps its name across runs so a large copy resumes; the folder fsync is shared.)
Running the same fetch again resumes: a file already here with the robot's size and sha256 is skipped,
a ``.part`` whose bytes match the start of the robot's file is continued from where it stopped.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any, Callable

from daemon.bus.client import Client, ClientTimeout
from daemon.ctl.exitcodes import Exit
from daemon.ctl.io import fail
from daemon.bus.protocol import CommandError
from daemon.bus.storage import fsync_dir

#: what a fetch without PATH takes: the datasets, the procedures' results and reports, the calibration
#: (docs/datasets.md's data dir). The daemon's own files beside them (ritad.lock, stop_latch.json,
#: worker.log) are its housekeeping, not results: only a PATH naming them copies them.
DEFAULT_PATHS = ("datasets", "procedures", "calibration")
CHUNK = 1 << 20  # bytes per files.read (the daemon's cap)
ATTEMPTS = 2  # a file that changes while it is copied is copied once more, then reported


class FetchError(Exception):
    """A file could not be copied faithfully (it kept changing on the robot)."""


@dataclass
class Progress:
    """Bytes done of the whole fetch; draws a bar on a terminal, nothing otherwise."""

    total: int
    tty: bool
    done: int = 0
    _last: float = field(default=0.0)

    def add(self, n: int, name: str) -> None:
        self.done += n
        now = time.monotonic()
        if self.tty and (now - self._last > 0.1 or self.done >= self.total):
            self._last = now
            frac = self.done / self.total if self.total else 1.0
            bar = "#" * int(frac * 30)
            sys.stderr.write(f"\r[{bar:30s}] {frac * 100:5.1f}% "
                             f"{self.done / 1e6:8.1f}/{self.total / 1e6:.1f} MB {name[-40:]:40s}")
            sys.stderr.flush()

    def end(self) -> None:
        if self.tty:
            sys.stderr.write("\n")


def local_target(dest: Path, rel: str) -> Path:
    """Where a robot path lands here; refuses names that would leave ``dest`` (a bad daemon's listing)."""
    p = PurePosixPath(rel)
    unsafe = any(part in ("..", "") or ":" in part or "\\" in part for part in p.parts)
    if p.is_absolute() or not p.parts or unsafe:
        raise FetchError(f"refusing the robot's path {rel!r}: it would leave {dest}")
    return dest.joinpath(*p.parts)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(CHUNK):
            h.update(block)
    return h.hexdigest()


def _resume_offset(c: Client, rel: str, part: Path, size: int, timeout: float) -> int:
    """Bytes of ``part`` that equal the start of the robot's file (0: start over)."""
    have = part.stat().st_size if part.exists() else 0
    if have == 0 or have > size:
        return 0
    remote = c.call("files.hash", timeout=timeout, path=rel, length=have)
    return have if remote["sha256"] == _sha256(part) else 0


def _download(c: Client, rel: str, part: Path, offset: int, chunk: int, timeout: float,
              progress: Progress) -> int:
    """Append the robot's bytes from ``offset`` to its end into ``part``, fsynced; returns the reads."""
    reads = 0
    with open(part, "ab" if offset else "wb") as f:
        f.truncate(offset)
        while True:
            meta, extra = c.call_raw("files.read", {"path": rel, "offset": offset, "length": chunk}, timeout)
            reads += 1
            data = bytes(extra[0].buffer) if extra else b""
            f.write(data)
            offset += len(data)
            progress.add(len(data), rel)
            if meta["eof"] or not data:
                break
        f.flush()
        os.fsync(f.fileno())
    return reads


def fetch_file(c: Client, rel: str, size: int, dest: Path, chunk: int = CHUNK, timeout: float = 30.0,
               progress: Progress | None = None, renamed_in: set[Path] | None = None) -> str:
    """Copy one file; returns "skipped", "resumed" or "fetched".

    The folder is fsynced after the rename, or, with ``renamed_in``, added to it for the caller
    to fsync once per folder (many small files).
    """
    progress = progress or Progress(size, False)
    target = local_target(dest, rel)
    if target.exists() and target.stat().st_size == size:
        if c.call("files.hash", timeout=timeout, path=rel)["sha256"] == _sha256(target):
            progress.add(size, rel)
            return "skipped"
    target.parent.mkdir(parents=True, exist_ok=True)
    part = target.with_name(f".{target.name}.part")
    how = "fetched"
    for _ in range(ATTEMPTS):
        offset = _resume_offset(c, rel, part, size, timeout)
        if offset:
            how = "resumed"
            progress.add(offset, rel)
        whole = _download(c, rel, part, offset, chunk, timeout, progress) == 1 and offset == 0
        # one read of the whole file cannot straddle a change; more reads are checked against the robot
        if whole or c.call("files.hash", timeout=timeout, path=rel)["sha256"] == _sha256(part):
            os.replace(part, target)
            if renamed_in is None:
                fsync_dir(target.parent)
            else:
                renamed_in.add(target.parent)
            return how
        part.unlink()  # changed on the robot while we copied it: once more from the start
        size = c.call("files.hash", timeout=timeout, path=rel, length=0)["size"]
    raise FetchError(f"{rel} kept changing on the robot while it was copied; try again later")


def _list(c: Client, path: str, timeout: float, given: bool) -> dict[str, Any]:
    """files.list of one path; a default folder the robot does not have yet (no job run) lists nothing."""
    try:
        return dict(c.call("files.list", timeout=timeout, path=path))
    except CommandError as exc:
        if given or exc.code != "not_found":
            raise
        return {"files": []}


def fetch(c: Client, paths: list[str], dest: Path, chunk: int = CHUNK, timeout: float = 30.0,
          tty: bool = False, say: Callable[[str], None] = print, quiet: bool = False) -> dict[str, Any]:
    """Copy every file under ``paths`` (DEFAULT_PATHS when empty) into ``dest``.

    ``quiet``: no line per file.
    """
    listing: dict[str, int] = {}
    for path in paths or DEFAULT_PATHS:
        r = _list(c, path, timeout, given=bool(paths))
        if r.get("truncated"):
            say(f"note: the robot listed only the first {len(r['files'])} files under {path or '.'!r}; "
                f"fetch its sub-folders one by one")
        listing.update({f["path"]: f["size"] for f in r["files"]})
    out: dict[str, Any] = {"to": str(dest), "fetched": [], "resumed": [], "skipped": [], "errors": {}}
    progress = Progress(sum(listing.values()), tty)
    renamed_in: set[Path] = set()
    try:
        for rel, size in sorted(listing.items()):
            try:
                how = fetch_file(c, rel, size, dest, chunk, timeout, progress, renamed_in)
            except ClientTimeout:
                raise  # the daemon is gone: no point in trying the next file
            except (CommandError, FetchError) as exc:
                out["errors"][rel] = exc.args[0]
                out.setdefault("changing" if isinstance(exc, FetchError) else "refused", []).append(rel)
                continue
            out[how].append(rel)
            if not tty and not quiet:
                say(f"{how:8s} {rel} ({size} bytes)")
    finally:
        progress.end()
        for folder in renamed_in:  # also after Ctrl-C: what was renamed stays renamed
            fsync_dir(folder)
    return out


def cmd_fetch(c: Client, a: argparse.Namespace) -> int:
    dest = Path(a.to)
    try:
        r = fetch(c, a.paths, dest, timeout=a.timeout or 30.0,
                  tty=sys.stderr.isatty() and not (a.json or a.quiet),
                  say=(lambda _: None) if a.json else print, quiet=a.quiet)
    except KeyboardInterrupt:
        print("\ninterrupted: run the same `ritactl fetch` again to resume", file=sys.stderr)
        return Exit.INTERRUPTED
    except OSError as exc:
        return fail(Exit.BAD_INPUT, "bad_input", f"cannot write under {dest}: {exc}", a.json)
    if a.json:
        print(json.dumps(r, indent=2))
    else:
        print(f"{len(r['fetched'])} fetched, {len(r['resumed'])} resumed, {len(r['skipped'])} already here "
              f"(same sha256), {len(r['errors'])} failed -> {dest}")
        for rel, msg in r["errors"].items():
            print(f"  FAILED {rel}: {msg}", file=sys.stderr)
    # a file that kept changing (or a listing we refuse) is a failed copy; a daemon error is REFUSED
    return Exit.FAIL if r.get("changing") else Exit.REFUSED if r["errors"] else Exit.OK


def add_parser(sub: Any) -> None:
    p = sub.add_parser("fetch", help="copy datasets, reports, plots and results from the robot to here",
                       description="Copy files from the robot's data dir over the bus; resumable: run it "
                                   "again after an interruption. Files already here with the same sha256 "
                                   "are skipped.")
    p.add_argument("paths", nargs="*", metavar="PATH",
                   help="file or folder relative to the robot's data dir, e.g. procedures/JOB or sim "
                        f"(default: {', '.join(DEFAULT_PATHS)}: datasets, results and reports, not the "
                        f"daemon's own files)")
    p.add_argument("--to", default="rita-data", metavar="DIR",
                   help="local folder to copy into, keeping the robot's layout (default: ./rita-data)")
    p.add_argument("--quiet", "-q", action="store_true",
                   help="no line per file: only the summary and failures")
    p.set_defaults(fn=cmd_fetch)
