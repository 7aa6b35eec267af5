"""One thread for every timeout ritad waits on: long polls, motions waiting for their end, the STOP's reply.

A ``threading.Timer`` per wait was a thread per long poll (the worker polls ``calib.inbox`` all the
time). Here each timeout is an entry in a heap that one owner thread serves: it sleeps until the
earliest deadline or until an earlier one is added. The callbacks are short (they complete a Future),
so one thread keeps them on time; a callback that raises is logged and the others still run.
"""
from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from typing import Callable

log = logging.getLogger(__name__)


class Timeout:
    """A scheduled call; ``cancel()`` before it is due and it never runs."""

    __slots__ = ("cancelled",)

    def __init__(self) -> None:
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True  # one writer per entry; the thread reads it once, under the lock


class Timeouts:
    """The owner thread of ritad's timeouts, started by the first ``call_later`` and ended by ``stop``."""

    def __init__(self, name: str = "timeouts") -> None:
        self._name = name
        self._cond = threading.Condition()
        self._heap: list[tuple[float, int, Timeout, Callable[[], None]]] = []
        self._order = itertools.count()  # equal deadlines run in the order they were asked for
        self._thread: threading.Thread | None = None
        self._stopped = False

    def call_later(self, delay_s: float, fn: Callable[[], None]) -> Timeout:
        """Run ``fn`` in this thread ``delay_s`` seconds from now, unless cancelled first."""
        entry = Timeout()
        with self._cond:
            if self._stopped:  # ritad is stopping: nothing waits for this timeout any more
                entry.cancelled = True
                return entry
            heapq.heappush(self._heap, (time.monotonic() + max(0.0, delay_s), next(self._order), entry, fn))
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
                self._thread.start()
            self._cond.notify()
        return entry

    def stop(self, timeout: float = 2.0) -> None:
        """Drop what is not due and end the thread (ritad's stop)."""
        with self._cond:
            self._stopped = True
            self._heap.clear()
            self._cond.notify()
            thread = self._thread
        if thread is not None:
            thread.join(timeout)

    def _due(self) -> list[tuple[Timeout, Callable[[], None]]] | None:
        """Wait for the next deadline; the entries due, or None when stopped."""
        with self._cond:
            while not self._stopped:
                now = time.monotonic()
                due = []
                while self._heap and self._heap[0][0] <= now:
                    _, _, entry, fn = heapq.heappop(self._heap)
                    if not entry.cancelled:
                        due.append((entry, fn))
                if due:
                    return due
                self._cond.wait(self._heap[0][0] - now if self._heap else None)
            return None

    def _run(self) -> None:
        while (due := self._due()) is not None:
            for entry, fn in due:
                if entry.cancelled:  # cancelled after it was taken from the heap
                    continue
                try:
                    fn()
                except Exception:  # one bad callback must not end every other timeout
                    log.exception("timeout callback failed")
