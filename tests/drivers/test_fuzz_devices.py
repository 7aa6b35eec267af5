"""Fuzzing the device drivers with hostile input: emScon byte streams and robot lines.

emScon: 11,000 random streams (valid packets, truncated, oversized, mutated, random
bytes; sent whole or split) reach the real ``EmsconTracker`` over TCP straight after
connecting, then EOF. Only the documented exceptions may escape (``DeviceLost`` from
``pump``; ``DeviceError`` and its subclasses from a command in flight) and the
points/events of every whole valid packet are delivered. ``test_faults_injection``
sends more of these streams through a live daemon.

Robot: random lines (noise, bad checksums, bad syntax, stray replies, unknown kinds,
events with random fields, over-long runs) are written into the fake base's pty in
front of the real ``SerialRobot``: each is counted in the right counter and the base
still answers.
"""
from __future__ import annotations

import socket
import struct
import time
from typing import Any

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers import robot_protocol as rp
from drivers.base import DeviceError, DeviceLost, DeviceURL
from drivers.emscon.adapter import EmsconTracker
from drivers.emscon.codec import (COMMANDS, MAX_PACKET, MEAS_VALUE, MEAS_VALUE2, encode_answer, encode_error,
                                  encode_result, encode_status_change)
from fakes.robot import SimRobot
from fakes.world import World
from fakes.worlds import sim_url
from tests.fuzzscale import cases, scaled
from tools.harness.load import hang_s

STREAMS = (1100, 300)  # hypothesis examples: full run, make-test sample
LINES = (560, 160)

FUZZ = dict(derandomize=True, deadline=None, database=None, suppress_health_check=list(HealthCheck))
int32 = st.integers(-(1 << 31), (1 << 31) - 1)

# ---------------------------------------------------------------------------- emScon packets


@st.composite
def valid_packet(draw: st.DrawFn) -> tuple[bytes, int, int]:
    """A whole to-client packet and what the adapter must publish for it: (bytes, points, events)."""
    kind = draw(st.sampled_from(["answer", "error", "change", "multi", "multi2", "single", "other"]))
    if kind == "answer":
        cmd = draw(st.sampled_from(sorted(COMMANDS)))
        status = draw(st.sampled_from([0, 0, 1, 10004]) | int32)
        return (encode_answer(cmd, 0) if status == 0 else encode_answer(cmd, status)), 0, 1
    if kind == "error":
        return encode_error(draw(int32), draw(int32)), 0, 1
    if kind == "change":
        return encode_status_change(draw(st.integers(0, 40) | int32)), 0, 1
    if kind in ("multi", "multi2"):
        n = draw(st.integers(0, 30))
        rng = np.random.default_rng(draw(st.integers(0, 1 << 32)))
        rec = np.zeros(n, MEAS_VALUE if kind == "multi" else MEAS_VALUE2)
        for name in rec.dtype.names:
            rec[name] = rng.integers(-1000, 1000, n) if rec.dtype[name].kind == "i" else rng.normal(0, 1e4, n)
        status = draw(st.sampled_from([0, 0, 0, 10004]))
        return encode_result(kind, status, rec), n, int(status != 0)
    if kind == "single":
        return (encode_result(draw(st.sampled_from(["single", "single2"])), draw(st.sampled_from([0, 3]))),
                0, 1)
    return encode_result(draw(st.sampled_from(["reflector_pos", "nivel"]))), 0, 1


@st.composite
def emscon_stream(draw: st.DrawFn) -> dict[str, Any]:
    """A stream of one category; ``clean`` streams are whole valid packets only."""
    packets = draw(st.lists(valid_packet(), max_size=6))
    body = b"".join(p[0] for p in packets)
    points, events = sum(p[1] for p in packets), sum(p[2] for p in packets)
    how = draw(st.sampled_from(["valid", "valid", "truncated", "oversized", "random", "mutated"]))
    if how == "truncated":
        last = draw(valid_packet())[0]
        body += last[:draw(st.integers(1, len(last) - 1))]
    elif how == "oversized":
        size = draw(st.one_of(st.integers(MAX_PACKET + 1, (1 << 31) - 1), st.integers(-(1 << 31), 7)))
        body += struct.pack("<ii", size, draw(int32)) + draw(st.binary(max_size=40))
    elif how == "random":
        body += draw(st.binary(min_size=1, max_size=300))
    elif how == "mutated":
        raw = bytearray(draw(valid_packet())[0])
        for _ in range(draw(st.integers(1, 4))):
            raw[draw(st.integers(0, len(raw) - 1))] ^= draw(st.integers(1, 255))
        body += bytes(raw)
    cuts = draw(st.one_of(st.just([]), st.lists(st.integers(1, max(1, len(body))), max_size=4)))
    return {"how": how, "body": body, "points": points, "events": events, "cuts": sorted(set(cuts)),
            "request": draw(st.sampled_from([None, None, None, "aim", "measure"]))}


def stream_key(s: dict[str, Any]) -> tuple[Any, ...]:
    return s["body"], tuple(s["cuts"]), s["request"]


class RawTracker(EmsconTracker):
    """The real adapter without its init sequence, so a stream reaches its reader at once."""

    def _init_sequence(self, c: Any) -> None:
        """Skip the handshake (the server here only plays back bytes)."""


class Playback:
    """A listener on 127.0.0.1:0 that plays one stream to each adapter connection, then EOF."""

    def __init__(self) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        port = self.listener.getsockname()[1]
        url = f"emscon://127.0.0.1:{port}?timeout=0.05&meas_time_ms=1&connect_timeout=2"
        self.emitted: list[tuple[str, dict[str, Any]]] = []
        self.tracker = RawTracker(DeviceURL.parse(url), emit=lambda t, p: self.emitted.append((t, p)))

    def play(self, s: dict[str, Any]) -> DeviceError:
        """Feed one stream, then EOF; return the documented error that ended it."""
        self.tracker.open()
        conn, _ = self.listener.accept()
        body, cuts = s["body"], s["cuts"]
        try:
            try:
                for a, b in zip([0, *cuts], [*cuts, len(body)]):
                    conn.sendall(body[a:b])
                    if b < len(body):
                        self._step(None)  # let the reader see the stream cut here
                conn.shutdown(socket.SHUT_WR)
                result = self._step(s["request"])
                for _ in range(1000):  # after EOF the adapter must report the loss, not spin
                    self._step(None)
            except DeviceError as exc:  # DeviceLost, DeviceTimeout and tracker status errors
                return exc
            raise AssertionError(f"the adapter never reported the closed connection (result {result})")
        finally:
            conn.close()
            self.tracker.close()

    def _step(self, request: str | None) -> Any:
        if request == "aim":
            return self.tracker.aim((1000.0, 200.0, -300.0))
        if request == "measure":
            return self.tracker.measure()
        return self.tracker.pump(0.01)


def test_emscon_streams_into_the_adapter() -> None:
    pb = Playback()
    n = [0]
    distinct: set[tuple[Any, ...]] = set()
    how: dict[str, int] = {}
    t0 = time.monotonic()

    @settings(max_examples=cases(*STREAMS), **FUZZ)
    @given(streams=st.lists(emscon_stream(), min_size=10, max_size=10, unique_by=stream_key))
    def run(streams: list[dict[str, Any]]) -> None:
        for s in streams:
            pb.emitted.clear()
            exc = pb.play(s)
            n[0] += 1
            distinct.add(stream_key(s))
            how[s["how"]] = how.get(s["how"], 0) + 1
            if s["request"] is None:
                assert isinstance(exc, DeviceLost), exc  # pump documents DeviceLost only
                points = sum(p["n"] for t, p in pb.emitted if t == "tracker.point")
                events = sum(1 for t, _ in pb.emitted if t == "tracker.event")
                if s["how"] in ("valid", "truncated"):
                    assert (points, events) == (s["points"], s["events"]), s
                    assert "EOF" in str(exc), exc
                elif s["how"] == "oversized":
                    assert (points, events) == (s["points"], s["events"]), s
                    assert "protocol error" in str(exc) and "lPacketSize" in str(exc), exc

    run()
    dt = time.monotonic() - t0
    print(f"\nemScon adapter fuzz: {n[0]} streams ({len(distinct)} distinct) in {dt:.1f} s {how}; counters "
          f"{pb.tracker.status()['counters']}")
    assert len(distinct) >= scaled(9_800, *STREAMS)  # with the 220 live streams below: over 10,000
    assert pb.tracker.status()["counters"]["protocol_errors"] > scaled(1000, *STREAMS)


# ---------------------------------------------------------------------------- robot lines

REPLY_KINDS, EVENT_KINDS = rp.REPLIES, rp.EVENTS
field_text = st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E, exclude_characters="$*,"),
                     max_size=12)
upper_word = st.text(st.characters(min_codepoint=ord("A"), max_codepoint=ord("Z")), min_size=1, max_size=8)
finite = st.floats(-1e6, 1e6).map(rp.num)


def frame(body: str, bad_checksum: int = 0) -> bytes:
    cs = int(rp.checksum(body), 16) ^ bad_checksum
    return f"${body}*{cs:02X}\r\n".encode()


@st.composite
def robot_line(draw: st.DrawFn) -> tuple[bytes, str | None]:
    """One line and the driver counter it must land in (None: ignored blank line)."""
    how = draw(st.sampled_from(["noise", "checksum", "syntax", "badseq", "stale", "unknown", "event",
                                "badevent", "overlong", "blank"]))
    fields = draw(st.lists(field_text, max_size=5))
    seq = str(draw(st.integers(5000, rp.SEQ_MAX)))  # the driver's own seqs stay far below
    if how == "noise":
        return b"\x01" + draw(st.binary(max_size=120)).replace(b"\n", b"?") + b"\n", "garbage"
    if how == "checksum":
        return frame(",".join([draw(upper_word), *fields]), draw(st.integers(1, 255))), "bad_checksum"
    if how == "syntax":
        kind = draw(st.one_of(st.just(""), st.text("abcxyz0123456789", min_size=1, max_size=6),
                              upper_word.map(str.lower)))
        return frame(",".join([kind, *fields])), "syntax"
    if how == "badseq":
        bad = draw(st.sampled_from(["0", "10000", "-1", "x", "1.5", " 7"]))
        return frame(",".join([draw(st.sampled_from(REPLY_KINDS + EVENT_KINDS)), bad, *fields])), "syntax"
    if how == "stale":
        return frame(",".join([draw(st.sampled_from(REPLY_KINDS)), seq, *fields])), "stale"
    if how == "unknown":
        kind = draw(upper_word.filter(lambda k: k not in REPLY_KINDS + EVENT_KINDS))
        return frame(",".join([kind, *fields])), "unexpected"
    if how == "event":
        if draw(st.booleans()):
            body = ",".join(["DONE", seq, draw(field_text), draw(finite), draw(finite), draw(finite),
                             *fields])
        else:
            body = ",".join(["FAULT", draw(st.sampled_from([seq, ""])), draw(field_text), *fields])
        return frame(body), "events"
    if how == "badevent":
        nums = [draw(st.one_of(finite, st.sampled_from(["", "x", "nan", "inf", "1e999"]))) for _ in range(3)]
        nums[draw(st.integers(0, 2))] = draw(st.sampled_from(["x", "nan", "inf", "1e999", ""]))
        return frame(",".join(["DONE", seq, "OK", *nums[:draw(st.integers(0, 3))]])), "syntax"
    if how == "overlong":
        return b"$" + b"A" * draw(st.integers(rp.MAX_LINE, 3 * rp.MAX_LINE)) + b"\n", "overlong"
    return draw(st.sampled_from([b"\n", b"\r\n", b"   \r\n"])), None


COUNTED = ("garbage", "bad_checksum", "syntax", "stale", "unexpected", "events", "overflows")


def expect_counts(lines: list[tuple[bytes, str | None]], before: dict[str, int],
                  after: dict[str, int]) -> None:
    want = {k: sum(1 for _, c in lines if c == k) for k in COUNTED}
    got = {k: after[k] - before[k] for k in COUNTED}
    overlong = sum(1 for _, c in lines if c == "overlong")
    # an over-long line is dropped as garbage or as an overflow, depending on how the reads fell
    assert got["garbage"] + got["overflows"] == want["garbage"] + overlong
    assert got["overflows"] <= overlong
    assert {k: got[k] for k in COUNTED[1:6]} == {k: want[k] for k in COUNTED[1:6]}


def test_robot_lines_into_the_driver() -> None:
    events: list[dict[str, Any]] = []
    world = World()  # registered weakly: held here for as long as the robot lives
    # no sample streams: the base's STATE lines would fill the pty between examples (the driver reads
    # it only in status()), and a drawn "$STATE"/"$INCL" line is a sample then, not an unknown kind.
    # Deterministic counters: the lines go out through the fake's own thread (PtyServer.inject: whole, in
    # order, ahead of the STATUS reply, never interleaved with a line of the base's), and the reply timeout
    # only catches a hang: a reply late on a busy machine is never retried and counted stale.
    robot = SimRobot(sim_url(world, f"state_hz=0&stream_hz=0&timeout={hang_s(10):g}"),
                     emit=lambda t, p: events.append(p) if t == "robot.event" else None)
    robot.open()
    n = [0]
    distinct: set[bytes] = set()
    t0 = time.monotonic()
    try:
        @settings(max_examples=cases(*LINES), **FUZZ)
        @given(lines=st.lists(robot_line(), min_size=24, max_size=24, unique_by=lambda x: x[0]))
        def run(lines: list[tuple[bytes, str | None]]) -> None:
            before, n_events = dict(robot.counters), len(events)
            robot.server.inject(b"".join(line for line, _ in lines))
            assert robot.status().state == "IDLE"  # the reply comes after every injected line
            assert robot.counters["retries"] == before["retries"]
            expect_counts(lines, before, robot.counters)
            assert len(events) - n_events == robot.counters["events"] - before["events"]
            n[0] += len(lines)
            distinct.update(line for line, _ in lines)

        run()
    finally:
        robot.shutdown()
    print(f"\nrobot line fuzz: {n[0]} lines ({len(distinct)} distinct) in {time.monotonic() - t0:.1f} s; "
          f"counters {robot.counters}")
    assert len(distinct) >= scaled(10_000, *LINES)
