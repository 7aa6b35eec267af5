"""The conformance kit's checks that move the robot (only with ``--allow-motion``): short and slow, each
ending with a STOP, forwards at most ~40 mm in all. Reusable by ``ritactl commission`` (the host watchdog,
STOP's braking distance).

Needs about 0.1 m clear ahead of the robot and room to turn 10° on the spot.
"""

from __future__ import annotations

import math
import time

from drivers import robot_protocol as rp
from drivers.robot_conformance_link import Check, Link, Received, ms, seq_of, verdict

#: how far a STATUS pose may stray from the commanded motion in odometry (mm, deg): its rounding
ODOMETRY_TOL_MM, ODOMETRY_TOL_DEG = 0.5, 0.1


def pose(link: Link) -> tuple[str, float, float, float] | None:
    """STATUS's state and odometry (x, y, heading), None when it does not come or does not parse."""
    _, got, _ = link.ask("STATUS")
    if got is None or got.msg is None or got.msg.kind != "STATUS":
        return None
    try:
        return got.msg.fields[1], got.msg.number(2, "x"), got.msg.number(3, "y"), got.msg.number(4, "h")
    except rp.ProtocolError:
        return None


def halt(link: Link) -> None:
    """STOP until acknowledged (at most 1 s): every motion check ends with it, whatever happened."""
    deadline = time.monotonic() + 1.0
    while time.monotonic() < deadline:
        seq, got, _ = link.ask("STOP")
        if got is not None and got.msg is not None and got.msg.kind == "ACK":
            return


def _kept_alive(link: Link, period: float = rp.DEFAULT_HOST_TIMEOUT_MS / 3000.0) -> None:
    """From now on the kit writes a line at least every ``period`` s, as a host must while its motion runs."""
    link.keepalive_s = period


def _end_of(link: Link, seq: int, timeout: float) -> Received | None:
    return link.wait_for(lambda m: m.kind in rp.EVENTS and seq_of(m) == seq, timeout)


def _motion(link: Link, kind: str, amount: float, speed: float) -> tuple[Received | None, Received | None]:
    """A MOVE/TURN and its end event (its ACK, its DONE/FAULT)."""
    seq, ack, _ = link.ask(kind, rp.num(amount), rp.num(speed))
    if ack is None or ack.msg is None or ack.msg.kind != "ACK":
        return ack, None
    return ack, _end_of(link, seq, abs(amount) / speed * 2 + 2.0)


def check_done(link: Link) -> Check:
    """MOVE 20 mm: DONE OK, odometry 20 mm further along its heading, STATUS IDLE after; TURN +10°: the
    heading grows (counter-clockwise), and back."""
    _kept_alive(link)
    try:
        start = pose(link)
        _, done = _motion(link, "MOVE", 20.0, 50.0)
        after = pose(link)
        _, turned = _motion(link, "TURN", 10.0, 20.0)
        turned_pose = pose(link)
        _motion(link, "TURN", -10.0, 20.0)
    finally:
        halt(link)
        link.keepalive_s = None
    if None in (start, after, turned_pose) or done is None or turned is None:
        return verdict(
            "done", False, "no DONE or STATUS", f"DONE {done and done.raw!r}, TURN {turned and turned.raw!r}"
        )
    (_, x0, y0, h0), (state, x1, y1, h1), (_, _, _, h2) = start, after, turned_pose  # type: ignore[misc]
    a = math.radians(h0)
    along = (x1 - x0) * math.cos(a) + (y1 - y0) * math.sin(a)
    turn = math.remainder(h2 - h1, 360.0)
    ok = (
        done.msg is not None
        and done.msg.fields[1:2] == ("OK",)
        and state == "IDLE"
        and abs(along - 20.0) <= ODOMETRY_TOL_MM
        and abs(turn - 10.0) <= ODOMETRY_TOL_DEG
    )
    return verdict(
        "done",
        ok,
        f"MOVE 20 mm: {along:.2f} mm along the heading, then {state}; TURN 10°: {turn:+.2f}°",
        "" if ok else f"DONE {done.raw!r}",
    )


def check_retry_move(link: Link) -> Check:
    """A MOVE resent while MOVING with its seq and arguments is acknowledged again and not executed twice;
    a new MOVE meanwhile is NAK BUSY."""
    _kept_alive(link)
    try:
        start = pose(link)
        seq = link.next_seq()
        line = rp.encode("MOVE", seq, 10, 10)
        first, again = link.ask_line(line), link.ask_line(line)
        _, busy, _ = link.ask("MOVE", 10, 10)
        end = _end_of(link, seq, 4.0)
        after = pose(link)
    finally:
        halt(link)
        link.keepalive_s = None
    acks = [
        r is not None and r.msg is not None and r.msg.kind == "ACK" and seq_of(r.msg) == seq
        for r in (first, again)
    ]
    busy_ok = busy is not None and busy.msg is not None and busy.msg.fields[1:2] == ("BUSY",)
    moved = math.hypot(after[1] - start[1], after[2] - start[2]) if start and after else float("nan")
    ok = all(acks) and busy_ok and end is not None and abs(moved - 10.0) <= ODOMETRY_TOL_MM
    return verdict(
        "retry_move",
        ok,
        f"resend answered {again.raw if again else None!r}; moved {moved:.2f} mm of 10",
        "" if busy_ok else f"a new MOVE while moving answered {busy.raw if busy else None!r}, not BUSY",
    )


def check_stop_braking(link: Link, protocol: int, speed: float = 50.0) -> list[Check]:
    """During a MOVE: HELLO is answered and the motion goes on (hello_while_moving); STOP is acknowledged
    and the wheels stand within v²/2a of STOP_DECEL_MM_S2 plus what the robot drove before the STOP
    arrived (stop_braking)."""
    _kept_alive(link)
    try:
        seq, ack, _ = link.ask("MOVE", 100, rp.num(speed))
        link.wait_for(lambda m: False, 0.2)  # 0.2 s of motion, kept alive
        hello = link.ask("HELLO", protocol, *((rp.DEFAULT_HOST_TIMEOUT_MS,) if protocol == 3 else ()))[1]
        t_status = time.monotonic()
        moving = pose(link)
        _, stop_ack, _ = link.ask("STOP")
        t_ack = time.monotonic()
        done = _end_of(link, seq, 2.0)
    finally:
        halt(link)
        link.keepalive_s = None
    hello_ok = (
        hello is not None
        and hello.msg is not None
        and hello.msg.kind == "VERSION"
        and moving is not None
        and moving[0] == "MOVING"
    )
    out = [
        verdict(
            "hello_while_moving",
            hello_ok,
            f"HELLO answered {hello.raw if hello else None!r}; then {moving[0] if moving else 'no STATUS'}",
        )
    ]
    if moving is None or done is None or done.msg is None or stop_ack is None:
        return out + [
            verdict("stop_braking", False, "no STATUS, STOP ACK or DONE", f"MOVE ACK {ack and ack.raw!r}")
        ]
    try:
        x2, y2 = done.msg.number(2, "x"), done.msg.number(3, "y")
    except rp.ProtocolError:
        return out + [verdict("stop_braking", False, f"DONE {done.raw!r} unreadable")]
    travelled = math.hypot(x2 - moving[1], y2 - moving[2])
    allowed = speed * (t_ack - t_status) + speed**2 / (2 * rp.STOP_DECEL_MM_S2) + ODOMETRY_TOL_MM
    ok = done.msg.fields[1:2] == ("STOPPED",) and travelled <= allowed
    return out + [
        verdict(
            "stop_braking",
            ok,
            f"{travelled:.2f} mm after the last STATUS at {rp.num(speed)} mm/s; allowed {allowed:.2f} mm",
            f"DONE {done.raw!r}",
        )
    ]


def check_watchdog(link: Link, protocol: int, caps: list[str], speed: float = 20.0) -> Check:
    """Version 3 with WATCHDOG: a MOVE, then silence; FAULT HOST_LOST after the host timeout (300 ms), not
    before; the robot halted within what it drives in that time plus braking; STOP clears the fault."""
    if protocol < 3 or rp.CAP_WATCHDOG not in caps:
        return Check("watchdog", "skip", f"protocol {protocol} without WATCHDOG: no host watchdog")
    timeout = rp.DEFAULT_HOST_TIMEOUT_MS / 1000.0
    try:
        start = pose(link)
        seq, ack, _ = link.ask("MOVE", 100, rp.num(speed))
        silent_from = link.last_write
        fault = link.wait_for(lambda m: m.kind in rp.EVENTS and seq_of(m) == seq, timeout + 1.5)
        halt(link)  # also clears the fault
        end = pose(link)
    finally:
        halt(link)
    if fault is None or fault.msg is None or start is None or end is None:
        return verdict(
            "watchdog", False, f"no FAULT within {timeout + 1.5:.1f} s of silence", f"ACK {ack and ack.raw!r}"
        )
    after = fault.t - silent_from
    drove = math.hypot(end[1] - start[1], end[2] - start[2])
    allowed = (
        speed * (timeout + rp.REPLY_BUDGET_S + rp.USB_LATENCY_S)
        + speed**2 / (2 * rp.STOP_DECEL_MM_S2)
        + ODOMETRY_TOL_MM
    )
    ok = (
        fault.msg.kind == "FAULT"
        and fault.msg.fields[1:2] == (rp.FAULT_HOST_LOST,)
        and after >= timeout - 0.005
        and drove <= allowed
        and end[0] == "IDLE"
    )
    return verdict(
        "watchdog",
        ok,
        f"{fault.msg.kind} {','.join(fault.msg.fields[1:2])} {ms(after)} after the last "
        f"host line; drove {drove:.2f} mm (allowed {allowed:.2f}); after STOP {end[0]}",
    )
