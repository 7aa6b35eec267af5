"""One running procedure: its dataset folder, its checkpointed state, and its bus conversation.

The state (``state.json``) holds the parameters, the observations gathered so far
and the names of completed steps; it is rewritten atomically after every step, so a
worker killed at any moment resumes where it stopped without re-measuring what is
already stored. Images go next to it as lossless PNG with a JSON sidecar.
"""
from __future__ import annotations

import json
import logging
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from calibration import __version__
from daemon.bus.client import Client
from daemon.bus.names import JobState
from daemon.bus.procedures import Resolved, cli_flags, get
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.bus.storage import Dataset, atomic_write_json
from daemon.compute.images import grey_loader

log = logging.getLogger("daemon.worker")


class Cancelled(Exception):
    """The operator cancelled the job."""


class Stopped(Exception):
    """The robot's stop was latched: this run ends at once; ``calib.resume`` continues it after release."""


class StepFailed(Exception):
    """A step failed for a reason the operator can act on; ``resumable`` says whether a resume can help."""

    def __init__(self, message: str, resumable: bool = True) -> None:
        super().__init__(message)
        self.resumable = resumable


def ended_with(exc: BaseException, message: str | None = None) -> str:
    """An error's message (``message``, else its own) with the notes added while the job ended (a cleanup
    that failed after it: ``JobContext.afterwards``)."""
    return "; ".join([str(exc) if message is None else message, *getattr(exc, "__notes__", ())])


class JobContext:
    """Bus access, progress reporting and persistence for one job."""

    def __init__(self, client: Client, job: dict[str, Any], data_dir: Path) -> None:
        self.client = client
        self.job_id: str = job["job"]
        self.procedure: str = job["procedure"]
        self.data_dir = Path(data_dir)
        self.root = self.data_dir / "procedures" / self.job_id
        self.state_path = self.root / "state.json"
        if self.state_path.exists():
            self.state = json.loads(self.state_path.read_text())
            self.resumed = True
        else:
            self.state = {"schema": 1, "job": self.job_id, "procedure": self.procedure,
                          "params": job.get("params", {}), "status": JobState.RUNNING, "done": [], "obs": {},
                          "started_ns": time.time_ns(), "software": __version__}
            self.resumed = False
        self.step = "start"  # the step in progress, named in a failure message
        self._params: Resolved | None = None
        self.dataset = Dataset(self.root, kind=f"procedure:{self.procedure}",
                               meta={"job": self.job_id, "params": self.state["params"],
                                     "software": __version__})
        self.checkpoint()

    # ------------------------------------------------------------------ state

    @property
    def params(self) -> Resolved:
        """The job's parameters, every default applied: ritad stored them resolved; a record an older version
        wrote (only the given ones) resolves the same way. Resolved on first use, inside the job's run, so a
        record that no longer checks fails its job, not the worker."""
        if self._params is None:
            self._params = get(self.procedure).resolve(self.state["params"])
        return self._params

    def definition(self, name: str, hint: str = "") -> dict[str, Any]:
        """A file parameter's JSON object: the job's, else the robot's installed file its declaration
        names."""
        given = getattr(self.params, name)
        if given is not None:
            return dict(given)
        p = get(self.procedure).param(name)
        path = self.data_dir / p.installed
        if not path.exists():
            hint = hint or f"pass it with ritactl {get(self.procedure).verb} {cli_flags(p)[0]} FILE"
            raise ValueError(f"{path} does not exist: {hint} or install it there")
        return dict(json.loads(path.read_text()))

    @property
    def obs(self) -> dict[str, Any]:
        return self.state["obs"]

    def done(self, step: str) -> bool:
        return step in self.state["done"]

    def mark_done(self, step: str) -> None:
        self.state["done"].append(step)
        self.checkpoint()

    def checkpoint(self) -> None:
        atomic_write_json(self.state_path, self.state)

    def finish(self, status: JobState) -> None:
        self.state["status"] = status
        self.state["finished_ns"] = time.time_ns()
        self.checkpoint()

    # ------------------------------------------------------------------ bus

    def call(self, cmd: str, timeout: float = 120.0, **args: Any) -> Any:
        self.check_cancel()
        try:
            return self.client.call(cmd, timeout=timeout, **args)
        except CommandError as exc:
            if exc.code == ErrorCode.STOPPED:  # a refused or aborted motion: the job stops here
                raise Stopped(exc.args[0]) from None
            raise

    @contextmanager
    def afterwards(self, cmd: str, timeout: float = 30.0, **args: Any) -> Iterator[None]:
        """Run the body, then ``cmd`` (e.g. ``tracker.stream.stop``): always, and past the stop check, since a
        STOP or a cancel must not leave a device streaming.

        The first error is the job's outcome: when the body raised (a STOP's ``Stopped``), a failing ``cmd``
        is logged and added to that error as a note (``ended_with``), never raised in its place; when the
        body ended well, a failing ``cmd`` fails the job as any call does.
        """
        try:
            yield
        except BaseException as exc:
            try:
                self.client.call(cmd, timeout=timeout, **args)
            except Exception as cleanup:  # noqa: BLE001 - whatever it was, it must not mask ``exc``
                note = f"{cmd} failed after it: {cleanup}"
                log.warning("[%s] %s ended the step; %s", self.job_id, type(exc).__name__, note)
                exc.add_note(note)
            raise
        self.client.call(cmd, timeout=timeout, **args)

    def report(self, kind: str, data: dict[str, Any]) -> None:
        try:
            self.client.call("calib.report", timeout=10, job=self.job_id, kind=kind, procedure=self.procedure,
                             data=data)
        except CommandError as exc:  # progress is best effort; the procedure goes on
            log.warning("could not report %s: %s", kind, exc)

    def progress(self, step: str, percent: float, waiting_for: str = "", **extra: Any) -> None:
        self.step = step
        log.info("[%s] %5.1f%% %s %s", self.job_id, percent, step, waiting_for)
        self.report("progress", {"step": step, "percent": round(percent, 1), "waiting_for": waiting_for,
                                 **extra})

    def check_cancel(self) -> None:
        """Before every bus call: a STOP or a cancel posted for this job ends it here."""
        self._ended_by(self.client.call("calib.inbox", timeout=10, job=self.job_id, timeout_s=0))

    def _ended_by(self, msg: Any) -> None:
        if msg and msg.get("stop"):
            raise Stopped(f"job {self.job_id} stopped: the robot's stop is latched")
        if msg and msg.get("cancel"):
            raise Cancelled(f"job {self.job_id} cancelled by the operator")

    def ask(self, question: str, choices: list[str] | None = None, timeout_s: float = 3600.0) -> str:
        """Prompt the operator (calib.prompt) and wait for ``calib.answer``."""
        self.report("prompt", {"question": question, "choices": choices or ["ok"]})
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            msg = self.client.call("calib.inbox", timeout=40, job=self.job_id, timeout_s=30)
            if not msg:
                continue
            self._ended_by(msg)
            answer = str(msg.get("answer", ""))
            if choices and answer not in choices:
                self.report("prompt", {"question": f"please answer one of {choices}: {question}",
                                       "choices": choices})
                continue
            return answer
        raise TimeoutError(f"no answer to {question!r} within {timeout_s:.0f} s")

    # ------------------------------------------------------------------ data

    def capture_image(self, name: str) -> tuple[str, dict[str, Any], np.ndarray]:
        """Software-trigger one frame, store it losslessly; returns (file, header, pixels)."""
        result, extra = self.client.call_raw("camera.capture", {"pixels": True, "save": False}, timeout=60)
        h = result["header"]
        pixels = np.frombuffer(extra[0].buffer, dtype=np.dtype(h["dtype"])).reshape(h["shape"]).copy()
        self.dataset.add_entry(name, {"camera": h, "job": self.job_id}, image=pixels)
        return f"{name}.png", h, pixels

    def load_image(self, file: str) -> np.ndarray:
        """A stored image as 8-bit grey for detection (its pixel format from its sidecar)."""
        return grey_loader(self.root)(file)
