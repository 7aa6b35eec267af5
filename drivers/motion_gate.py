"""The robot's motion gate: where a latched STOP becomes a halt on the line, whatever the link does.

The gate belongs to the robot's device unit (the adapter and its owner thread), not to the bus: a
STOP from any thread only *requests* a halt here and wakes the owner; the owner writes the STOP line
at its next read slice, ahead of any reply it is waiting for, and again first after the HELLO of
every (re)connect while the gate is latched. A request is answered (its Future completes) when the
base acknowledges a STOP written after it, however many reconnects that takes: a lost link delays
the halt, it never drops it. While latched, the adapter refuses to write a motion line.

Thread-safe: ``engage``/``release`` come from the bus, ``halt_due``/``halted`` from the owner thread.
"""
from __future__ import annotations

import threading
from concurrent.futures import Future
from typing import Callable


class MotionGate:
    """Latched or open, and how many halt requests the base has not yet acknowledged."""

    def __init__(self, latched: bool = False) -> None:
        self._lock = threading.Lock()
        self._latched = latched
        #: halt requests made / acknowledged by the base; a latched start owes the base one halt
        self._requested = 1 if latched else 0
        self._acked = 0
        self._waiters: list[tuple[int, Future]] = []
        self._wake: Callable[[], None] = lambda: None
        self._on_halted: Callable[[], None] = lambda: None

    def bind(self, wake: Callable[[], None]) -> None:
        """The owner's wake-up (the adapter's ``wake``): called on every halt request."""
        self._wake = wake

    def on_halted(self, fn: Callable[[], None]) -> None:
        """Called (in the owner thread) when the base acknowledged every pending halt."""
        self._on_halted = fn

    @property
    def latched(self) -> bool:
        return self._latched

    def engage(self) -> Future:
        """Latch and request a halt; the Future completes when the base has acknowledged a STOP."""
        fut: Future = Future()
        with self._lock:
            self._latched = True
            self._requested += 1
            self._waiters.append((self._requested, fut))
        self._wake()
        return fut

    def owe(self) -> None:
        """One more halt owed, with nobody waiting for it (a connect while latched: STOP first)."""
        with self._lock:
            self._requested += 1

    def release(self) -> None:
        """Motions may be written again (a halt still owed is still sent)."""
        with self._lock:
            self._latched = False

    def halt_due(self) -> int | None:
        """The newest request the owner must still send a STOP for, else None."""
        with self._lock:
            return self._requested if self._requested > self._acked else None

    @property
    def pending(self) -> bool:
        return self.halt_due() is not None

    def halted(self, upto: int) -> None:
        """The base acknowledged a STOP written after request ``upto`` (owner thread)."""
        with self._lock:
            self._acked = max(self._acked, upto)
            done = [f for n, f in self._waiters if n <= self._acked]
            self._waiters = [(n, f) for n, f in self._waiters if n > self._acked]
            clear = self._requested <= self._acked
        for fut in done:
            if not fut.done():
                fut.set_result(True)
        if clear:
            self._on_halted()
