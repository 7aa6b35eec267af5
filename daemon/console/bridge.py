"""The console's side of the bus: latest telemetry per topic, and commands.

One reader thread keeps the newest telemetry message per topic (plus, in a short
ring, the event topics a page must not miss). Nothing here ever waits on a browser,
so a slow page cannot slow the reader or the daemon. Pictures are not subscribed to:
full frames (12 MB) would not fit a robot's Wi-Fi, so each tab pulls small JPEGs with
``camera.preview`` (daemon/ritad/preview.py). Commands run in a thread pool with one
bus Client per thread (a DEALER socket is not thread-safe), so ``robot.stop`` never
queues behind a long ``robot.move``.
"""
from __future__ import annotations

import collections
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

from daemon.bus.client import Client, Subscriber
from daemon.bus.protocol import CommandError
from daemon.bus.names import Topic
from daemon.console.series import Series

#: topics whose every message matters to the page (prompts, results, motion ends), not just the last
EVENT_TOPICS = (Topic.CALIB_PROMPT, Topic.CALIB_RESULT, Topic.ROBOT_EVENT, Topic.TRACKER_EVENT, Topic.LOG)
#: kept as the latest value (the page's latch banner) and also sent as an event: a STOP and its release
#: within one state period would coalesce into "released", and a page must still close a motion dialog
#: opened before that STOP (it may not send a motion confirmed across a latch)
LATCH_EVENT_TOPICS = (Topic.ROBOT_LATCH,)
EVENT_RING = 200


class Bridge:
    """Bus connection for the web server: ``latest``, ``events``, ``frame``, ``call()``."""

    def __init__(self, make_client: Callable[[], Client], workers: int = 6) -> None:
        self._make_client = make_client
        self._local = threading.local()
        self.pool = ThreadPoolExecutor(workers, thread_name_prefix="console-call")
        # STOP has a thread (and so a bus connection) of its own: never behind six slow calls
        self.urgent = ThreadPoolExecutor(1, thread_name_prefix="console-stop")
        self._lock = threading.Lock()
        self.latest: dict[str, dict[str, Any]] = {}   # topic -> {seq, t_ns, data}
        self.events: collections.deque[dict[str, Any]] = collections.deque(maxlen=EVENT_RING)
        self.event_no = 0
        self.series = Series()   # the plotted values, kept with their history for every tab
        self.link = {"bus": "connecting", "error": ""}
        self.role = "unknown"
        self.hello: dict[str, Any] = {}
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    # ------------------------------------------------------------------ commands
    def _client(self) -> Client:
        c = getattr(self._local, "client", None)
        if c is None:
            c = self._local.client = self._make_client()
        return c

    def call(self, cmd: str, args: dict[str, Any] | None = None, timeout: float | None = None) -> Any:
        """One bus command from a pool thread (raises CommandError / ClientTimeout like Client)."""
        return self._client().call_raw(cmd, args or {}, timeout)[0]

    def call_raw(self, cmd: str, args: dict[str, Any],
                 timeout: float | None = None) -> tuple[Any, list[bytes]]:
        result, frames = self._client().call_raw(cmd, args, timeout)
        return result, [f.bytes for f in frames]

    def probe_role(self) -> str:
        """viewer or operator+: ``calib.answer`` without arguments is refused before validation for a
        viewer (``forbidden``) and fails validation (``bad_args``) for anyone allowed, so nothing happens."""
        try:
            self.call("calib.answer", {})
        except CommandError as exc:
            if exc.code == "forbidden":
                return "viewer"
            if exc.code == "bad_args":
                return "operator"
            raise
        return "operator"

    # ------------------------------------------------------------------ readers
    def start(self) -> None:
        """Ask ``hello`` and the role (raising when the daemon does not answer in the client's timeout),
        then start the readers."""
        c = self._make_client()
        try:
            self.hello = c.call("hello")
            tel = c.subscriber()
        finally:
            c.close()
        self.role = self.probe_role()
        self._snapshot()
        self.link = {"bus": "up", "error": ""}
        t = threading.Thread(target=self._telemetry_loop, args=(tel,), name="console-telemetry", daemon=True)
        t.start()
        self._threads.append(t)

    def _snapshot(self) -> None:
        """Clone pattern: the daemon's last value per topic, for a console started late."""
        snap = self.call("state", timeout=5.0)
        with self._lock:
            for topic, entry in (snap.get("latest") or {}).items():
                if topic not in EVENT_TOPICS and topic not in self.latest:
                    self.latest[topic] = entry

    def _telemetry_loop(self, sub: Subscriber) -> None:
        last_msg = time.monotonic()
        while not self._stop.is_set():
            msg = sub.recv(0.5)
            now = time.monotonic()
            if msg is None:
                # daemon.health comes every health_interval_s (default 1 s): 5 s of silence is a lost link
                if now - last_msg > 5.0 and self.link["bus"] == "up":
                    self.link = {"bus": "silent", "error": "no telemetry for 5 s"}
                continue
            last_msg = now
            if self.link["bus"] != "up":
                self.link = {"bus": "up", "error": ""}
            topic, body, _ = msg
            entry = {"seq": body.get("seq"), "t_ns": body.get("t_ns"), "data": body.get("data")}
            self.series.add(topic, entry["t_ns"], entry["data"], time.time() * 1000.0)
            with self._lock:
                self.latest[topic] = entry
                if topic in EVENT_TOPICS or topic in LATCH_EVENT_TOPICS or topic.startswith("calib."):
                    self.event_no += 1
                    self.events.append({"no": self.event_no, "topic": topic, **entry})
        sub.close()

    # ------------------------------------------------------------------ reads for the web side
    def state_since(self, seen: dict[str, int]) -> dict[str, Any]:
        """Topics whose seq changed since ``seen`` (updated in place): coalesced, never a backlog."""
        out = {}
        with self._lock:
            for topic, entry in self.latest.items():
                if seen.get(topic) != entry["seq"]:
                    seen[topic] = entry["seq"]
                    out[topic] = entry
        return out

    def events_since(self, no: int) -> list[dict[str, Any]]:
        with self._lock:
            return [e for e in self.events if e["no"] > no]

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(2.0)
        self.pool.shutdown(wait=False, cancel_futures=True)
        self.urgent.shutdown(wait=False, cancel_futures=True)
