"""SerialRobot.wake: a pump in progress returns at once (a job queued for the owner thread need not
wait for the pump's timeout), and a wake does not cut a command's wait for its reply short."""
from __future__ import annotations

import threading

from fakes.robot import SimRobot
from fakes.world import World, WorldParams
from fakes.worlds import sim_url


def test_wake_ends_a_long_pump_and_commands_still_get_their_replies() -> None:
    world = World(WorldParams(seed=1, base_has_inclinometer=True))
    robot = SimRobot(sim_url(world, "state_hz=0"))
    robot.open()
    try:
        pump = threading.Thread(target=robot.pump, args=(60.0,), daemon=True)
        pump.start()
        robot.wake()
        pump.join(30.0)  # without the wake, the pump would run its 60 s
        assert not pump.is_alive()
        robot.wake()  # a wake between pumps (a job already running): the command still waits for its reply
        assert robot.status().state == "IDLE"
        robot.pump(0.05)  # the flag left set ends this pump early; nothing breaks
        assert robot.status().state == "IDLE"
        assert robot.counters["retries"] == 0
    finally:
        robot.close()
        robot.shutdown()
