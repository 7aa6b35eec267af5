"""``robot.commission``: the base's part of ``ritactl commission``, the conformance kit's checks run by
ritad on its own port.

The kit (``python -m drivers.robot_conformance``, drivers/robot_conformance*.py) must see what the driver
hides (a reply's exact timing, a ``t_us`` that goes back, a base that keeps driving when its host goes
quiet), so it talks over its own :class:`Link`, not through :class:`SerialRobot`. ritad owns the port, so
the checks run as one job of the robot's owner thread: the driver closes the port, the kit opens it as the
driver does, runs the base's checks (reachable, versions, reply latency, ``t_us``; with ``allow_motion``
the host watchdog and STOP's braking, each a short motion ending in STOP), closes it, and the driver opens
it again (HELLO, a latched STOP first, its streams). Meanwhile ritad publishes no robot telemetry.

STOP means stop during the kit too: the kit's :class:`Link` holds the robot's motion gate, so an operator's
STOP (any source) is written by the kit at its next read slice (5 ms), its ACK awaited and told to the
gate (the STOP's Future completes), and the kit aborted: the checks it kept from their end are FAIL
"STOP during the kit: not run" naming the halt, and the driver's port is opened again as after any run
(latched: STOP first after its HELLO). ritad exiting (SIGTERM) while the kit runs halts the base the same
way before the owner thread ends.
"""
from __future__ import annotations

from typing import Any, Callable

import serial

from daemon.bus.protocol import CommandError, ErrorCode
from daemon.ritad.server import Handler, Request
from daemon.ritad.rigs import RobotRig
from drivers import robot_conformance_checks as cc
from drivers import robot_conformance_motion as cm
from drivers import robot_protocol as rp
from drivers.base import DeviceError, DeviceLost, Robot
from drivers.robot import SerialRobot
from drivers.robot_conformance import rp_clock, unreachable
from drivers.robot_conformance_link import Check, KitStopped, Link, not_run
from drivers.robot_port import open_error, open_port

#: STATUS round trips timed for the latency check (the kit's default)
POLLS = 50
#: the kit's read slice (s), as ``python -m drivers.robot_conformance`` opens the port
KIT_SLICE_S = 0.005


#: the base's checks ``robot.commission`` reports, in the kit's order (t_us_width follows a passed t_us)
KIT_CHECKS = ("stop_before_hello", "versions", "latency", "t_us", "hello_while_moving", "stop_braking",
              "watchdog")


def kit_checks(link: Link, *, baudrate: int, allow_motion: bool, clock_s: float) -> list[Check]:
    """The kit's checks that a commissioning needs, in the kit's order; the first must reach the base. A STOP
    (the link's gate) ends the run: the checks not run are FAIL, naming it."""
    results: list[Check] = []
    try:
        _kit(link, results, baudrate=baudrate, allow_motion=allow_motion, clock_s=clock_s)
    except KitStopped as exc:
        results += not_run(results, KIT_CHECKS, str(exc))
    return results


def _kit(link: Link, results: list[Check], *, baudrate: int, allow_motion: bool, clock_s: float) -> None:
    """The checks of :func:`kit_checks`, each appended to ``results`` as it ends."""
    results.append(cc.check_stop_before_hello(link))
    if unreachable(results):
        return
    versions, protocol, caps = cc.check_versions(link)
    results.append(versions)
    results.append(cc.check_latency(cc.poll_status(link, POLLS), baudrate, link.timeout))
    if rp_clock(protocol, caps):
        results += cc.check_clock(cc.status_t_us(link, clock_s))
    else:
        results.append(Check("t_us", "warn", f"protocol {protocol} without CLOCK", "the host times the "
                             "base by arrival (σ 6 ms): update the firmware to protocol 2 or 3"))
    if allow_motion:
        results += cm.check_stop_braking(link, protocol)
    else:
        results += [Check(name, "skip", "moves the robot: run with --allow-motion")
                    for name in ("hello_while_moving", "stop_braking")]
    if rp.CAP_WATCHDOG not in caps:  # the kit skips it; a robot in service needs it: seen without a motion
        results.append(Check("watchdog", "fail", f"protocol {protocol} without WATCHDOG",
                             "a crashed ritad cannot stop a move: update the firmware to protocol 3"))
    elif allow_motion:
        results.append(cm.check_watchdog(link, protocol, caps))
    else:
        results.append(Check("watchdog", "skip", "moves the robot: run with --allow-motion"))


def _kit_port(robot: SerialRobot, target: str) -> Any:
    """The port opened as ``python -m drivers.robot_conformance`` opens it (DTR and RTS as the driver's)."""
    try:
        return open_port(target, robot.url.scheme, baudrate=robot.baudrate, timeout=KIT_SLICE_S,
                         write_timeout=robot.reply_timeout, dtr=bool(robot.dtr), rts=bool(robot.rts))
    except (serial.SerialException, OSError) as exc:
        raise DeviceLost(open_error(target, exc)) from exc


def run_on_port(robot: Robot, allow_motion: bool, clock_s: float,
                exiting: Callable[[], bool] = lambda: False) -> dict[str, Any]:
    """In the robot's owner thread: the driver's port handed to the kit and back (see the module's text);
    ``exiting``: ritad is stopping (the kit halts the base and ends)."""
    if not isinstance(robot, SerialRobot):
        raise DeviceError(f"{type(robot).__name__} is no serial base: the kit cannot check it",
                          code="not_supported")
    if robot.status().state == "MOVING":  # the kit's first line is a STOP: it would cut a motion short
        raise DeviceError("the base is moving: run the base's checks when it stands", code="robot_busy")
    target = robot.port_target()
    robot.close()
    try:
        port = _kit_port(robot, target)
        try:  # the driver's gate: a STOP meanwhile goes out within the kit's read slice, as the driver's
            link = Link(port, robot.reply_timeout, gate=robot.gate, exiting=exiting,
                        halt_tries=robot.retries + 1)
            checks = kit_checks(link, baudrate=robot.baudrate, allow_motion=allow_motion, clock_s=clock_s)
        finally:
            port.close()
    finally:
        robot.open()  # DeviceLost here: the runner reconnects as after any lost link (a halt owed goes first)
    return {"port": target, "checks": [c.to_dict() for c in checks]}


def commission_handlers(rob: RobotRig) -> dict[str, Handler]:
    def run(req: Request) -> Any:
        allow, clock_s = bool(req.args["allow_motion"]), float(req.args["clock_s"])
        if allow and req.args["confirm"] is not True:
            raise CommandError(ErrorCode.CONFIRM_REQUIRED, "robot.commission with allow_motion moves the "
                                                           "robot: send it again with confirm=true")

        def guarded(robot: Robot) -> dict[str, Any]:  # in the owner thread: a STOP may have come meanwhile
            if allow:
                rob.latch.guard(req.cmd, f"{req.peer.split(' (', 1)[0]} ({req.role})")
            return run_on_port(robot, allow, clock_s, exiting=lambda: rob.runner.stopping)

        return rob.job(guarded, timeout=90.0 + 2 * clock_s)

    return {"robot.commission": run}
