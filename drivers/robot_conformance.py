"""Conformance kit for a robot base's firmware: ``python -m drivers.robot_conformance URL [--allow-motion]``.

Runs the checks of docs/robot-protocol.md against any base the robot driver reaches (``serial:///dev/
ttyUSB0?baudrate=115200``, ``socket://``, ``rfc2217://``; the port is opened as the driver opens it,
DTR and RTS held low) and prints one line per check: PASS, FAIL, WARN or SKIP, its name, the measured
value. Without ``--allow-motion`` the checks that move the robot are skipped, and said so.

Exit codes: 0 every check run passed (WARN and SKIP lines may remain: read them); 1 a check failed;
2 bad arguments or URL; 3 the base cannot be reached (the port does not open, or no reply within the
boot window); 4 stopped by Ctrl-C or SIGTERM: a STOP was written to the base first, and the checks not
run are FAIL saying so (stderr says whether the base acknowledged the STOP). ``--json`` prints the
results as one JSON object instead.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from typing import Any, Callable

import serial

from drivers import robot_conformance_checks as cc
from drivers import robot_conformance_motion as cm
from drivers.base import DeviceURL
from drivers.motion_gate import MotionGate
from drivers.robot import SerialRobot
from drivers.robot_conformance_link import SLICE_S, VERDICTS, Check, KitStopped, Link, not_run
from drivers.robot_port import open_error, open_port

EXIT_PASS, EXIT_FAIL, EXIT_USAGE, EXIT_UNREACHABLE, EXIT_STOPPED = 0, 1, 2, 3, 4
MOTION_CHECKS = ("done", "retry_move", "hello_while_moving", "stop_braking", "watchdog")
#: every check of a run, in its order (t_us_width follows t_us only when the rate passed)
CHECKS = ("stop_before_hello", "versions", "nak_checksum", "nak_unknown", "nak_range", "nak_syntax",
          "noise_ignored", "lowercase_hex", "retry_status", "seq_echo", "latency", "t_us", "streams",
          *MOTION_CHECKS, "framing")


def run_checks(
    link: Link,
    *,
    baudrate: int,
    allow_motion: bool,
    polls: int = 50,
    clock_s: float = 1.0,
    stream_s: float = 1.0,
) -> list[Check]:
    """Every check, in an order that leaves each in a known state; the first must reach the base. A STOP
    (the link's gate) ends the run: the checks not run are FAIL, saying so."""
    results: list[Check] = []
    try:
        _run(link, results, baudrate=baudrate, allow_motion=allow_motion, polls=polls, clock_s=clock_s,
             stream_s=stream_s)
        link.pump()  # a STOP asked after the last check's last read still goes out
    except KitStopped as exc:
        results += not_run(results, CHECKS, str(exc))
    return results


def _run(link: Link, results: list[Check], *, baudrate: int, allow_motion: bool, polls: int, clock_s: float,
         stream_s: float) -> None:
    """The checks of :func:`run_checks`, each appended to ``results`` as it ends."""
    results.append(cc.check_stop_before_hello(link))
    if unreachable(results):
        return
    if not any(r.msg is not None for r in link.log):  # it talks, but in nothing the kit can read
        results.append(cc.check_framing(link))
        return
    start = len(link.log)
    versions, protocol, caps = cc.check_versions(link)
    results.append(versions)
    results += cc.check_naks(link)
    results.append(cc.check_retry_status(link))
    polls_done = cc.poll_status(link, polls)
    results += [cc.check_seq(polls_done), cc.check_latency(polls_done, baudrate, link.timeout)]
    if rp_clock(protocol, caps):
        results += cc.check_clock(cc.status_t_us(link, clock_s))
    else:
        results.append(Check("t_us", "skip", f"protocol {protocol} without CLOCK"))
    results += cc.check_streams(link, caps, seconds=stream_s)
    _run_motions(link, results, protocol, caps, allow_motion)
    results.append(cc.check_framing(link, start))


def _run_motions(link: Link, results: list[Check], protocol: int, caps: list[str],
                 allow_motion: bool) -> None:
    if not allow_motion:
        results += [Check(name, "skip", "moves the robot: run with --allow-motion") for name in MOTION_CHECKS]
        return
    results.append(cm.check_done(link))
    results.append(cm.check_retry_move(link))
    results += cm.check_stop_braking(link, protocol)
    results.append(cm.check_watchdog(link, protocol, caps))


def rp_clock(protocol: int, caps: list[str]) -> bool:
    return protocol >= 2 and "CLOCK" in caps


def unreachable(results: list[Check]) -> bool:
    return (
        bool(results)
        and results[0].name == "stop_before_hello"
        and results[0].value.startswith("nothing read")
    )


def exit_code(results: list[Check], stopped: bool = False) -> int:
    if stopped:
        return EXIT_STOPPED
    if unreachable(results):
        return EXIT_UNREACHABLE
    return EXIT_FAIL if any(r.verdict == "fail" for r in results) else EXIT_PASS


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m drivers.robot_conformance", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("url", help="the base's robot URL, e.g. serial:///dev/ttyUSB0?baudrate=115200")
    ap.add_argument(
        "--allow-motion",
        action="store_true",
        help="run the checks that move the robot (about 40 mm forwards, 10 degrees): clear its path",
    )
    ap.add_argument("--polls", type=int, default=50, help="STATUS round trips timed (default 50)")
    ap.add_argument("--json", action="store_true", help="print the results as JSON")
    try:
        args = ap.parse_args(argv)
    except SystemExit as exc:
        return EXIT_USAGE if exc.code else EXIT_PASS
    try:
        robot = SerialRobot(DeviceURL.parse(args.url))  # the driver's own URL rules and options
        if args.polls < 5:
            raise ValueError(f"--polls {args.polls}: at least 5")
    except ValueError as exc:
        print(f"robot_conformance: {exc}", file=sys.stderr)
        return EXIT_USAGE
    target = robot.port_target()
    try:
        port = open_port(
            target,
            robot.url.scheme,
            baudrate=robot.baudrate,
            timeout=SLICE_S,
            write_timeout=robot.reply_timeout,
            dtr=bool(robot.dtr),
            rts=bool(robot.rts),
        )
    except (serial.SerialException, OSError) as exc:
        print(f"robot_conformance: {open_error(target, exc)}", file=sys.stderr)
        return EXIT_UNREACHABLE
    gate = MotionGate()  # Ctrl-C and SIGTERM engage it: the link writes STOP at its next read slice
    restore = _stop_on_signals(gate)
    link = Link(port, robot.reply_timeout, gate=gate, stop_by="Ctrl-C or SIGTERM",
                halt_tries=robot.retries + 1)
    try:
        results = run_checks(link, baudrate=robot.baudrate, allow_motion=args.allow_motion, polls=args.polls)
    finally:
        restore()
        port.close()
    if link.stopped:
        print(f"robot_conformance: stopped: {link.stopped}", file=sys.stderr)
    _print(results, args.json, target, link.stopped)
    return exit_code(results, bool(link.stopped))


def _stop_on_signals(gate: MotionGate) -> Callable[[], None]:
    """SIGINT and SIGTERM engage ``gate`` (from a thread: the gate's lock may be held by the interrupted main
    thread); returns what puts the previous handlers back. Only the main thread can set handlers."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    sigs = (signal.SIGINT, signal.SIGTERM)
    previous = {sig: signal.getsignal(sig) for sig in sigs}
    for sig in sigs:
        signal.signal(sig, lambda *_: threading.Thread(target=gate.engage, daemon=True).start())

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    return restore


def _print(results: list[Check], as_json: bool, target: str, stopped: str = "") -> None:
    code = exit_code(results, bool(stopped))
    if as_json:
        out: dict[str, Any] = {"port": target, "exit": code, "checks": [r.to_dict() for r in results]}
        if stopped:
            out["stopped"] = stopped
        print(json.dumps(out, indent=1))
        return
    for r in results:
        print(r.line())
    counts = {v: sum(1 for r in results if r.verdict == v) for v in VERDICTS}
    print(
        f"{counts['pass']} passed, {counts['fail']} failed, {counts['warn']} warned, "
        f"{counts['skip']} skipped "
        f"(exit {code})"
    )


if __name__ == "__main__":
    sys.exit(main())
