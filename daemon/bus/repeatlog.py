"""Rate-limited logging of repeated messages: the first of a kind at once, then at most one line per
window, carrying the count of those held back. A client retrying a refused request in a loop must
not flood the journal, and the count still tells the operator how often it happened."""
from __future__ import annotations

import time
from typing import Any, Callable, Generic, Hashable, TypeVar

K = TypeVar("K", bound=Hashable)


class RepeatGate(Generic[K]):
    """Which occurrences of a kind of message (``key``) to log; not thread-safe (callers lock or own it)."""

    def __init__(self, window_s: float = 60.0, clock: Callable[[], float] = time.monotonic,
                 max_keys: int = 1000) -> None:
        self.window_s = window_s
        self._clock = clock
        self._max_keys = max_keys
        self._seen: dict[K, list[Any]] = {}  # key -> [when last logged, held back since, last one's payload]

    def admit(self, key: K, payload: Any = None) -> int | None:
        """None: hold this occurrence back (counted, ``payload`` kept for :meth:`overdue`); else log it,
        with this many held back before it."""
        now = self._clock()
        entry = self._seen.get(key)
        if entry is not None and now - entry[0] < self.window_s:
            entry[1] += 1
            entry[2] = payload
            return None
        if len(self._seen) >= self._max_keys:  # many kinds: forget the quiet ones, stay bounded
            self._seen = {k: v for k, v in self._seen.items() if now - v[0] < self.window_s}
        self._seen[key] = [now, 0, payload]
        return int(entry[1]) if entry else 0

    def overdue(self) -> list[tuple[K, int, Any]]:
        """Kinds whose window ended with occurrences held back: (key, how many, the last one's payload).
        Log them now (the count would otherwise wait for the next occurrence, which may never come);
        their windows restart."""
        now = self._clock()
        out = []
        for key, entry in self._seen.items():
            if entry[1] and now - entry[0] >= self.window_s:
                out.append((key, int(entry[1]), entry[2]))
                entry[:] = [now, 0, None]
        return out


def times(n: int, window_s: float) -> str:
    """The suffix a rate-limited line carries: `` (x37 in the last 60 s)``."""
    return f" (x{n} in the last {window_s:g} s)"
