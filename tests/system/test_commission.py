"""``ritactl commission`` on the fakes: it passes on the simulated robot, and each injected device defect
fails the matching check with the measured value named (issue 32, Build 3).

ritad runs in-process on the fakes; the worker's run of the job (``run_job``, the product's code) runs in a
thread beside ``ritactl`` or in the test's thread. The robot base runs at real-time speed (``time_scale=1``):
the watchdog and braking checks see real motions. Runs are short (``duration_s`` 2-3 s): the tracker clock's
σ is then shown and skipped (it is judged from 60 s on), which a test of the verdict logic covers below.
"""
from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any, Callable

import pytest

from daemon.bus.client import Client
from daemon.bus.protocol import CommandError
from daemon.bus.datasets import validate_folder
from daemon.bus.procedures import COMMISSION
from daemon.compute.commission import compute_commission
from daemon.ctl.main import main as ritactl
from daemon.ritad import config
from daemon.worker.__main__ import run_job
from tests.drivers.test_robot_conformance_stop import is_moving, record_lines
from tests.ritad_up import SMALL_CAMERA, ritad_in_process
from tools.harness.stop_rig import wait_for

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]  # whole procedures through ritad (~5-15 s each)

#: where the simulated robot's reflector stands, tracker frame (README): the tracker locks onto it
REFLECTOR = [2800.0, -2500.0, -830.0]
#: a base powered on 5000 s ago: its t_us is above 2^32 µs, so the clock's width shows (a fresh one warns)
UP_S = 5000.0
BASE = f"sim:?time_scale=1&clock_offset_s={UP_S:g}"
#: the checks each device's part reports, by name
TRACKER_CHECKS = {"record_time", "packet_rate", "frame_cleared", "environment", "clock_sigma"}
CAMERA_CHECKS = {"ptp_role", "ptp_offset", "timestamp_unit", "timestamp_latch", "link_speed", "packet_size",
                 "resends", "pixel_format"}
BASE_CHECKS = {"stop_before_hello", "versions", "latency", "t_us", "t_us_width", "watchdog", "hello_while_moving",
               "stop_braking", "t_us_resets"}


def _ptp(cfg: config.Config) -> None:
    cfg.camera.ptp = True


def worker_once(endpoint: str, data_dir: Path, out: dict[str, Any]) -> None:
    """The calibration worker's handling of the next job (its own client, as the worker process)."""
    w = Client(endpoint, timeout=30)
    try:
        job = None
        for _ in range(10):
            job = job or w.call("calib.next", timeout=20, timeout_s=2)
        assert job, "no job for the worker"
        out["result"] = run_job(w, job, data_dir)
    finally:
        w.close()


def commission(tmp: Path, params: dict[str, Any], configure: Callable[[config.Config], None] | None = None,
               **devices: str) -> tuple[dict[str, Any], Path]:
    """One commissioning job on a fresh ritad with ``devices``; its result and its dataset folder."""
    with ritad_in_process(tmp / "rt", tmp / "data", configure=configure, **devices) as (d, c):
        data = Path(c.call("data.dir")["data_dir"])
        job = c.call("calib.start", procedure=COMMISSION.name, params={"duration_s": 2.0, **params})["job"]
        out: dict[str, Any] = {}
        worker_once(d.server.endpoints[0], data, out)
        assert out["result"] is not None, json.loads((data / "procedures" / job / "state.json").read_text())
        return out["result"], data / "procedures" / job


def by_name(result: dict[str, Any]) -> dict[str, dict[str, str]]:
    names = [c["name"] for c in result["checks"]]
    assert len(names) == len(set(names)), names
    return {c["name"]: c for c in result["checks"]}


def test_ritactl_commission_passes_on_the_simulated_robot(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    """Every check of every device, the motions allowed: exit 0, one line per check with its value; the
    stored report validates and recomputes to the same checks."""
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", camera=SMALL_CAMERA, robot=BASE) as (d, c):
        data = Path(c.call("data.dir")["data_dir"])
        out: dict[str, Any] = {}
        worker = threading.Thread(target=worker_once, args=(d.server.endpoints[0], data, out), daemon=True)
        worker.start()
        code = ritactl(["--endpoint", d.server.endpoints[0], "--timeout", "120", "commission",
                        "--duration-s", "3", "--reflector", *map(str, REFLECTOR), "--allow-motion", "--yes"])
        worker.join(60)
    printed = capsys.readouterr().out
    result = out["result"]
    checks = by_name(result)
    assert set(checks) == TRACKER_CHECKS | CAMERA_CHECKS | BASE_CHECKS
    not_passed = {n: (c["verdict"], c["value"], c["detail"]) for n, c in checks.items()
                  if c["verdict"] != "pass"}
    # not measurable in this run, each saying why: the clock's σ under 60 s, a camera without PTP
    assert not_passed.keys() == {"clock_sigma", "ptp_role", "ptp_offset", "timestamp_latch"}, not_passed
    assert {v for v, _, _ in not_passed.values()} == {"skip"}, not_passed
    assert code == 0 and result["verdict"] == "ok", printed
    for c in checks.values():  # the ritactl lines: verdict, device, check and the measured value
        assert f"{c['verdict'].upper():4}  {c['device']:7} {c['name']:18} {c['value']}" in printed
    assert "FAULT HOST_LOST" in checks["watchdog"]["value"] and "above 2^32" in checks["t_us_width"]["detail"]
    folder = Path(result["dataset"])
    assert validate_folder(folder) == []
    state = json.loads((folder / "state.json").read_text())
    assert compute_commission(state["obs"])["checks"] == result["checks"]  # judged from the stored evidence
    stored = json.loads((folder / "result.json").read_text())
    stored["checks"][0]["verdict"] = "fine"  # not a verdict: the schema names it
    (folder / "result.json").write_text(json.dumps(stored))
    assert any("fine" in str(p) and p.file == "result.json" for p in validate_folder(folder)), \
        validate_folder(folder)


def test_a_fresh_base_and_no_motion_skip_what_they_cannot_show_and_say_why(tmp_path: Path) -> None:
    """A base up for less than 71.6 min cannot show its clock's width: that check skipped with its reason,
    the clock's other checks passed; the motions skipped without --allow-motion."""
    result, _ = commission(tmp_path, {"devices": "base"}, robot="sim:?time_scale=1&clock_offset_s=100")
    checks = by_name(result)
    assert checks["t_us"]["verdict"] == "pass"
    assert checks["t_us_width"]["verdict"] == "skip" and "71.6 min" in checks["t_us_width"]["detail"]
    assert {checks[n]["verdict"] for n in ("watchdog", "stop_braking")} == {"skip"}
    assert "--allow-motion" in checks["watchdog"]["value"] and result["verdict"] == "ok"


def test_a_tracker_that_keeps_another_clients_frame_fails_frame_cleared(tmp_path: Path) -> None:
    result, folder = commission(tmp_path, {"devices": "tracker", "reflector_approx_trk": REFLECTOR},
                                tracker="sim:?time_scale=0.002&frame_held=1")
    c = by_name(result)["frame_cleared"]
    assert c["verdict"] == "fail", c
    assert "transformation applied: (100, 50, -20) mm, (0, 0, -5)°" in c["value"]  # fakes/tracker_frames.py
    assert result["verdict"] == "fail" and validate_folder(folder) == []


def test_a_tracker_at_3_packets_a_second_fails_packet_rate(tmp_path: Path) -> None:
    """A server without ES_SP_TcpDataPacketRate (before LTD706) keeps its own 3 packets/s: asked 10."""
    old_server = "sim:?time_scale=0.002&packet_rate_hz=3&fail=SetLongSystemParameter=NotImplemented"
    params = {"devices": "tracker", "reflector_approx_trk": REFLECTOR, "duration_s": 3.0}
    result, _ = commission(tmp_path, params, tracker=old_server)
    c = by_name(result)["packet_rate"]
    assert c["verdict"] == "fail", c
    measured = float(c["value"].split(" packets/s")[0])
    assert 2.0 <= measured <= 4.0 and "expected 10/s" in c["value"] and "asked 10" in c["value"], c
    assert by_name(result)["frame_cleared"]["verdict"] == "pass"  # only the matching check


def test_a_camera_that_won_the_ptp_election_fails_ptp_role(tmp_path: Path) -> None:
    result, _ = commission(tmp_path, {"devices": "camera"}, configure=_ptp,
                           camera=SMALL_CAMERA + "&ptp=Master")
    c = by_name(result)["ptp_role"]
    assert c["verdict"] == "fail" and "PtpStatus Master" in c["value"], c
    assert "PtpSlaveOnly" in c["detail"] and by_name(result)["pixel_format"]["verdict"] == "pass"


def test_a_locked_ptp_camera_passes_ptp_role_and_offset(tmp_path: Path) -> None:
    result, _ = commission(tmp_path, {"devices": "camera"}, configure=_ptp,
                           camera=SMALL_CAMERA + "&ptp=Slave")
    checks = by_name(result)
    assert checks["ptp_role"]["verdict"] == "pass" and checks["ptp_offset"]["verdict"] == "pass", checks
    latch = checks["timestamp_latch"]
    assert latch["verdict"] in ("pass", "skip"), latch  # skip: inconclusive, the trigger took longer


def test_a_base_with_a_32_bit_t_us_fails_on_its_wrap(tmp_path: Path) -> None:
    """The counter wraps 0.5 s after ritad first reads it (fakes/robot_defects.py): ritad's map of the base's
    clock, which restarts when it goes back, counts it; the kit's poll may see it too."""
    result, _ = commission(tmp_path, {"devices": "base"}, robot="sim:?time_scale=1&defects=t_us_32bit")
    checks = by_name(result)
    failed = {n: checks[n]["value"] + " " + checks[n]["detail"] for n in ("t_us", "t_us_resets")
              if checks[n]["verdict"] == "fail"}
    assert failed, checks
    assert any("went back" in text for text in failed.values()), failed
    assert result["verdict"] == "fail"


def test_a_base_without_a_host_watchdog_fails_watchdog(tmp_path: Path) -> None:
    result, _ = commission(tmp_path, {"devices": "base", "allow_motion": True},
                           robot=f"{BASE}&defects=no_watchdog")
    c = by_name(result)["watchdog"]
    assert c["verdict"] == "fail" and "no FAULT" in c["value"], c
    assert by_name(result)["stop_braking"]["verdict"] == "pass"


def test_a_version_2_base_fails_watchdog_without_a_motion(tmp_path: Path) -> None:
    """A base without WATCHDOG (protocol 2): a crashed ritad could not stop its moves; its VERSION says so."""
    result, _ = commission(tmp_path, {"devices": "base"}, robot=f"{BASE}&max_protocol=2")
    c = by_name(result)["watchdog"]
    assert c["verdict"] == "fail" and c["value"] == "protocol 2 without WATCHDOG", c
    assert by_name(result)["versions"]["verdict"] == "pass"  # a version-2 base is a conforming one


def test_a_device_that_is_down_is_one_failed_check_naming_why() -> None:
    obs = {"devices": ["tracker"], "tracker": {"state": "FAULT", "reason": "connection refused",
                                               "error": "tracker is FAULT: connection refused"}}
    result = compute_commission(obs)
    assert result["verdict"] == "fail" and result["checks"] == [
        {"device": "tracker", "name": "measured", "verdict": "fail",
         "value": "tracker is FAULT: connection refused",
         "detail": "fix this first: no other check of it ran"}]


def _kit_moving(endpoint: str, fake: Any, out: dict[str, Any]) -> threading.Thread:
    """``robot.commission allow_motion confirm`` from a client of its own (its reply or error in ``out``),
    returned once the kit's first MOVE is under way."""
    def run() -> None:
        with Client(endpoint, timeout=120) as k:
            try:
                out["reply"] = k.call("robot.commission", allow_motion=True, clock_s=0.5, confirm=True)
            except CommandError as exc:
                out["error"] = exc

    kit = threading.Thread(target=run, daemon=True)
    kit.start()
    wait_for(lambda: is_moving(fake), 60, "the kit's MOVE under way")
    return kit


def test_a_stop_from_another_client_halts_the_base_during_the_kits_motions(tmp_path: Path) -> None:
    """``robot.commission allow_motion confirm`` from one client, ``robot.stop`` from another while the kit's
    MOVE runs: the base hears STOP and no motion line after it, the STOP's reply says it was acknowledged,
    the commission's reply names the stop, and motions are refused while latched."""
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", robot=BASE) as (d, c):
        fake = d.rigs.robot.runner.device.fake
        heard, out = record_lines(fake), {}
        kit = _kit_moving(d.server.endpoints[0], fake, out)
        t_stop = time.monotonic()
        reply = c.call("robot.stop", timeout=30)
        kit.join(timeout=60)
        after = [kind for t, kind in list(heard) if t >= t_stop]
        assert reply["stopped"] is True and reply["latched"] is True, reply  # the base acknowledged it
        assert not is_moving(fake) and "STOP" in after and not {"MOVE", "TURN"} & set(after), after
        assert not kit.is_alive() and "error" not in out, out
        checks = {ch["name"]: ch for ch in out["reply"]["checks"]}
        assert checks["watchdog"]["verdict"] == "fail", checks["watchdog"]
        assert checks["watchdog"]["value"] == "STOP during the kit: not run", checks["watchdog"]
        assert "an operator's STOP" in checks["watchdog"]["detail"], checks["watchdog"]
        with pytest.raises(CommandError) as exc:
            c.call("robot.move", distance_mm=10, confirm=True)
        assert exc.value.code == "stopped"
        assert c.call("robot.status")["state"] == "IDLE"


def test_ritad_stopping_during_the_kits_motions_halts_the_base_first(tmp_path: Path) -> None:
    """SIGTERM's path (the daemon stops the robot's owner thread first) while the kit's MOVE runs: the kit
    writes STOP, aborts, and the owner thread ends; no motion line after."""
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", robot=BASE) as (d, _):
        fake = d.rigs.robot.runner.device.fake
        heard, out = record_lines(fake), {}
        kit = _kit_moving(d.server.endpoints[0], fake, out)
        t_stop = time.monotonic()
        d.rigs.robot.runner.stop(timeout=30)  # what Daemon.stop does first
        assert not d.rigs.robot.runner.is_alive()
        after = [kind for t, kind in list(heard) if t >= t_stop]
        assert not is_moving(fake) and "STOP" in after and not {"MOVE", "TURN"} & set(after), after
        kit.join(timeout=60)
        checks = {ch["name"]: ch for ch in out["reply"]["checks"]}
        assert "ritad exiting" in checks["watchdog"]["detail"], checks["watchdog"]
