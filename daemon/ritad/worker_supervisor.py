"""The calibration worker process, kept running beside ritad (restarted when it exits)."""
from __future__ import annotations

import logging
import subprocess
import time
from pathlib import Path
from typing import Callable

log = logging.getLogger("ritad")
RETRY_S = 5.0  # a worker that dies at once is retried slowly


class WorkerSupervisor:
    """Starts ``command()`` with its output appended to ``log_path``; ``tend()`` restarts it."""

    def __init__(self, command: Callable[[], list[str]], log_path: Path, enabled: bool = True) -> None:
        self._command = command  # called at each start: the endpoint is known only once the bus is bound
        self._log_path = log_path
        self.enabled = enabled
        self.process: subprocess.Popen | None = None
        self._next_start = 0.0
        self._stopped = False

    @property
    def pid(self) -> int | None:
        return None if self.process is None else self.process.pid

    def tend(self) -> None:
        """Start the worker if it is not running (called from the supervisor loop)."""
        if not self.enabled or self._stopped:
            return
        if self.process is not None and self.process.poll() is None:
            return
        if time.monotonic() < self._next_start:
            return
        self._next_start = time.monotonic() + RETRY_S
        if self.process is not None:
            log.warning("calibration worker exited with %s; restarting it", self.process.returncode)
        with open(self._log_path, "ab") as log_file:  # the child keeps its own copy of the descriptor
            self.process = subprocess.Popen(self._command(), stdout=log_file, stderr=subprocess.STDOUT)

    def stop(self, grace_s: float = 3.0) -> None:
        """Terminate the worker (kill it after ``grace_s``); ``tend`` starts no new one afterwards."""
        self._stopped = True
        if self.process is None or self.process.poll() is not None:
            return
        self.process.terminate()
        try:
            self.process.wait(grace_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
