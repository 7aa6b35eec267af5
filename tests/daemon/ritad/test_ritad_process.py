"""ritad --sim as a real process: READY through a fake NOTIFY_SOCKET, status, capture, SIGTERM."""
import json
import signal
import socket
import time
from pathlib import Path

import pytest

from daemon.bus.client import Client
from fakes.operator import lock_on_robot
from fakes.launch import start_ritad
from tools.harness.load import hang_s


@pytest.fixture
def ritad(tmp_path):
    """ritad --sim with a fake NOTIFY_SOCKET and a 2 s watchdog (fakes/launch.py)."""
    r = start_ritad(tmp=tmp_path, env={"WATCHDOG_USEC": "2000000"}, timeout=30, keep_notify=True)
    r.sock.settimeout(0.2)
    try:
        yield r.proc, r.endpoint, r.sock, r.messages, tmp_path
    finally:
        r.stop()


def test_ready_status_capture_and_clean_sigterm(ritad):
    proc, endpoint, sock, messages, tmp_path = ritad
    with Client(endpoint, timeout=10) as c:
        h = c.wait_ready()
        assert h["alive"] is True
        lock_on_robot(c)  # like an operator: point the tracker at the robot's reflector first
        r = c.call("capture", timeout=60, label="it")
        entry = Path(r["path"])
        meta = json.loads(entry.read_text())
        assert (entry.parent / meta["image_file"]).stat().st_size > 1000
        assert meta["tracker"]["x"] == pytest.approx(r["tracker"]["x"])
        assert meta["robot"]["state"] in ("IDLE", "MOVING")
        assert json.loads((entry.parent / "dataset.json").read_text())["entries"][0]["image"] == meta["image_file"]
    # watchdog pings flow while everything is alive
    end = time.monotonic() + 3
    pings = 0
    while time.monotonic() < end and pings < 2:
        try:
            pings += sock.recv(4096).count(b"WATCHDOG=1")
        except socket.timeout:
            pass
    assert pings >= 2
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(hang_s(10)) == 0  # a clean exit; how soon: bench/bench_daemon.py (SIGTERM → exit)
    rest = []
    while True:
        try:
            rest.append(sock.recv(4096))
        except socket.timeout:
            break
    assert any(b"STOPPING=1" in m for m in rest)


def test_bad_requests_do_not_stop_the_daemon(ritad):
    import zmq

    proc, endpoint, *_ = ritad
    ctx = zmq.Context.instance()
    s = ctx.socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    s.connect(endpoint)
    for payload in (b"garbage", b"\x93\x01\x02\x03", b"x" * (2 << 20)):
        s.send(payload)
        assert s.poll(5000)
        s.recv()
    s.close()
    with Client(endpoint, timeout=10) as c:
        assert c.call("ping")["pong"] is True
        with pytest.raises(Exception, match="confirm"):
            c.call("robot.move", distance_mm=10.0)
    assert proc.poll() is None


def test_one_world_for_all_fakes(ritad):
    """The tracker and camera fakes see the robot where the base fake moved it."""
    import numpy as np

    proc, endpoint, *_ = ritad
    with Client(endpoint, timeout=10) as c:
        c.wait_ready()
        p0 = lock_on_robot(c)
        shot0, extra0 = c.call_raw("camera.capture", {"pixels": True}, timeout=60)
        before = np.array(c.call("sim.truth")["abs_H_rob"])
        c.call("robot.move", timeout=60, distance_mm=15.0, speed_mm_s=50.0, confirm=True)
        after = np.array(c.call("sim.truth")["abs_H_rob"])
        p1 = c.call("tracker.measure", timeout=60)
        shot1, extra1 = c.call_raw("camera.capture", {"pixels": True}, timeout=60)
        rob_H_cam = np.array(c.call("sim.truth")["rob_H_cam"])
    moved_truth = after[:3, 3] - before[:3, 3]
    assert np.linalg.norm(moved_truth) == pytest.approx(15.0, abs=1e-6)
    assert np.dot(moved_truth / 15.0, before[:3, 0]) > 0.999999  # along the heading
    moved_seen = np.array(p1["abs_xyz"]) - np.array(p0["abs_xyz"])
    assert np.linalg.norm(moved_seen - moved_truth) < 0.1  # 10 µm tracker noise per coordinate
    # the camera rendered the moved robot: its true pose in the frame header, and different pixels
    assert np.allclose(np.array(shot1["header"]["sim_abs_H_cam"]), after @ rob_H_cam, atol=1e-6)
    px0 = np.frombuffer(extra0[0].buffer, np.uint8).astype(float)
    px1 = np.frombuffer(extra1[0].buffer, np.uint8).astype(float)
    assert np.abs(px1 - px0).mean() > 5.0
