"""The plate survey started from the page: ``ritactl plate survey`` as a child process, on this laptop.

The survey computes where the photographs are (docs/operations.md, "Plate survey"); the
console runs on that laptop, so it runs the very same verb, ``ritactl --json plate survey
FOLDER --plate DESIGN --out OUT``: one code path with one set of checks, messages and exit
codes, and numpy/OpenCV stay out of the console process (which keeps serving the live view
while the survey takes a core). The verb's ``[ 37.0%] step`` lines on stderr are the
progress; its JSON on stdout is the surveyed plate (exit 0 ok, 1 warn) or the error object.
One survey at a time; *Cancel* terminates the child (the design file is never written, the
output only atomically at the end).
"""
from __future__ import annotations

import asyncio
import json
import re
import sys
import time
from pathlib import Path
from typing import Any

from daemon.bus.protocol import CommandError, ErrorCode

SURVEY_ARGV = (sys.executable, "-m", "daemon.ctl.main", "--json", "plate", "survey")
PROGRESS_LINE = re.compile(r"^\[\s*([0-9.]+)%\]\s*(.*)$")
EXIT_TEXT = {0: "ok", 1: "warn"}  # daemon/ctl/exitcodes.py: a finished survey's verdict


def _path(value: Any, what: str) -> Path:
    if not isinstance(value, str) or not value.strip():
        raise CommandError(ErrorCode.BAD_ARGS, f"plate survey: {what} is empty: give a path on this computer")
    return Path(value.strip()).expanduser().resolve()


def read_plate_file(value: Any) -> dict[str, Any]:
    """A plate definition on this laptop (the survey's output or any plate.json), for
    ``calib.plate.upload``."""
    path = _path(value, "the plate file")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise CommandError(ErrorCode.BAD_ARGS,
                           f"plate upload: cannot read {path}: {type(exc).__name__}: {exc}") from None
    if not isinstance(doc, dict):
        raise CommandError(ErrorCode.BAD_ARGS, f"plate upload: {path} holds a {type(doc).__name__}, "
                                               f"not a plate definition (a JSON object)")
    return doc


class Survey:
    """The console's one survey: ``state`` is what the pages show (``version`` counts its changes)."""

    def __init__(self) -> None:
        self.state: dict[str, Any] = {"state": "idle", "version": 0}
        self._proc: asyncio.subprocess.Process | None = None
        self._watcher: asyncio.Task[None] | None = None  # held: the event loop keeps only weak references

    def _set(self, **fields: Any) -> None:
        self.state = {**self.state, **fields, "version": self.state["version"] + 1}

    @property
    def running(self) -> bool:
        return self.state["state"] == "running"

    async def start(self, args: dict[str, Any]) -> dict[str, Any]:
        """Start ``ritactl plate survey`` with the page's folder, design and output (paths on this laptop)."""
        if self.running:
            raise CommandError(ErrorCode.BUSY, "plate survey: one is already running (Cancel it first)")
        folder, plate, out = (_path(args.get(k), w) for k, w in (("folder", "the photo folder"),
                                                                ("plate", "the design file"),
                                                                ("out", "the output file")))
        self._proc = await asyncio.create_subprocess_exec(
            *SURVEY_ARGV, str(folder), "--plate", str(plate), "--out", str(out),
            stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
        self._set(state="running", folder=str(folder), plate=str(plate), out=str(out), percent=0.0,
                  step="starting", started=time.time(), message="", result=None, exit=None, cancelled=False,
                  error="", took_s=None)
        self._watcher = asyncio.create_task(self._watch(self._proc))
        return {"started": True, "folder": str(folder), "out": str(out)}

    async def _progress(self, stream: asyncio.StreamReader, tail: list[str]) -> None:
        async for raw in stream:
            line = raw.decode(errors="replace").rstrip()
            if m := PROGRESS_LINE.match(line):
                self._set(percent=float(m.group(1)), step=m.group(2))
            elif line:
                tail[:] = (tail + [line])[-5:]  # kept for a child that dies without its JSON

    async def _watch(self, proc: asyncio.subprocess.Process) -> None:
        tail: list[str] = []
        assert proc.stdout is not None and proc.stderr is not None
        out, _ = await asyncio.gather(proc.stdout.read(), self._progress(proc.stderr, tail))
        code = await proc.wait()
        took = round(time.time() - self.state["started"], 1)
        try:
            doc = json.loads(out) if out.strip() else {}
        except ValueError:
            doc = {}
        if code in EXIT_TEXT and isinstance(doc.get("survey"), dict):
            self._set(state="done", exit=code, percent=100.0, step="done", took_s=took, result=_summary(doc),
                      message=doc["survey"].get("message", ""))
        elif self.state.get("cancelled"):
            self._set(state="cancelled", exit=code, took_s=took, message="cancelled: nothing was written")
        else:
            why = doc.get("message") or " / ".join(tail) or f"ritactl plate survey ended with exit {code}"
            self._set(state="failed", exit=code, took_s=took, message=why, error=doc.get("error", "failed"))

    def cancel(self) -> dict[str, Any]:
        if not self.running or self._proc is None:
            raise CommandError(ErrorCode.BAD_ARGS, "plate survey: none is running")
        self._set(cancelled=True)
        self._proc.terminate()
        return {"cancel_requested": True}

    def close(self) -> None:
        if self._proc is not None and self._proc.returncode is None:
            self._proc.terminate()


def _summary(plate: dict[str, Any]) -> dict[str, Any]:
    """What the page shows of a surveyed plate: verdict, per-nest seat and 1σ, per-photograph residuals."""
    rep = plate["survey"]
    return {"verdict": rep.get("verdict"), "message": rep.get("message"),
            "nests": {c: {k: n.get(k) for k in ("ref_P_nst_mm", "sigma_mm", "views")}
                      for c, n in rep.get("nests", {}).items()},
            "views": [{k: v.get(k)
                       for k in ("image", "corners", "corner_rms_px", "ring_residual_px", "rings_missing")}
                      for v in rep.get("views", [])],
            "skipped": rep.get("skipped", {}), "sigma_corner_px": rep.get("sigma_corner_px"),
            "sigma_ring_px": rep.get("sigma_ring_px")}
