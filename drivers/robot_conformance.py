"""Conformance kit for a robot base's firmware: ``python -m drivers.robot_conformance URL [--allow-motion]``.

Runs the checks of docs/robot-protocol.md against any base the robot driver reaches (``serial:///dev/
ttyUSB0?baudrate=115200``, ``socket://``, ``rfc2217://``; the port is opened as the driver opens it,
DTR and RTS held low) and prints one line per check: PASS, FAIL, WARN or SKIP, its name, the measured
value. Without ``--allow-motion`` the checks that move the robot are skipped, and said so.

Exit codes: 0 every check run passed (WARN and SKIP lines may remain: read them); 1 a check failed;
2 bad arguments or URL; 3 the base cannot be reached (the port does not open, or no reply within the
boot window). ``--json`` prints the results as one JSON object instead.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

import serial

from drivers import robot_conformance_checks as cc
from drivers import robot_conformance_motion as cm
from drivers.base import DeviceURL
from drivers.robot import SerialRobot
from drivers.robot_conformance_link import SLICE_S, VERDICTS, Check, Link
from drivers.robot_port import open_error, open_port

EXIT_PASS, EXIT_FAIL, EXIT_USAGE, EXIT_UNREACHABLE = 0, 1, 2, 3
MOTION_CHECKS = ("done", "retry_move", "hello_while_moving", "stop_braking", "watchdog")


def run_checks(
    link: Link,
    *,
    baudrate: int,
    allow_motion: bool,
    polls: int = 50,
    clock_s: float = 1.0,
    stream_s: float = 1.0,
) -> list[Check]:
    """Every check, in an order that leaves each in a known state; the first must reach the base."""
    results = [cc.check_stop_before_hello(link)]
    if unreachable(results):
        return results
    if not any(r.msg is not None for r in link.log):  # it talks, but in nothing the kit can read
        return results + [cc.check_framing(link)]
    start = len(link.log)
    versions, protocol, caps = cc.check_versions(link)
    results += [versions, *cc.check_naks(link), cc.check_retry_status(link)]
    polls_done = cc.poll_status(link, polls)
    results += [cc.check_seq(polls_done), cc.check_latency(polls_done, baudrate, link.timeout)]
    if rp_clock(protocol, caps):
        results += cc.check_clock(cc.status_t_us(link, clock_s))
    else:
        results.append(Check("t_us", "skip", f"protocol {protocol} without CLOCK"))
    results += cc.check_streams(link, caps, seconds=stream_s)
    if allow_motion:
        results += [
            cm.check_done(link),
            cm.check_retry_move(link),
            *cm.check_stop_braking(link, protocol),
            cm.check_watchdog(link, protocol, caps),
        ]
    else:
        results += [Check(name, "skip", "moves the robot: run with --allow-motion") for name in MOTION_CHECKS]
    results.append(cc.check_framing(link, start))
    return results


def rp_clock(protocol: int, caps: list[str]) -> bool:
    return protocol >= 2 and "CLOCK" in caps


def unreachable(results: list[Check]) -> bool:
    return (
        bool(results)
        and results[0].name == "stop_before_hello"
        and results[0].value.startswith("nothing read")
    )


def exit_code(results: list[Check]) -> int:
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
    try:
        results = run_checks(
            Link(port, robot.reply_timeout),
            baudrate=robot.baudrate,
            allow_motion=args.allow_motion,
            polls=args.polls,
        )
    finally:
        port.close()
    _print(results, args.json, target)
    return exit_code(results)


def _print(results: list[Check], as_json: bool, target: str) -> None:
    code = exit_code(results)
    if as_json:
        out: dict[str, Any] = {"port": target, "exit": code, "checks": [r.to_dict() for r in results]}
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
