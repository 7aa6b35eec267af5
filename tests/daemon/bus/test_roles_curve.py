"""Roles over CURVE on tcp://127.0.0.1 port 0, against a simulated ritad with devices READY.

A viewer watches (status, state, telemetry, frames) and gets ``forbidden`` for motion,
jobs and captures; an operator does those; only an admin changes keys (over the bus, or
root with the files); revocation and role changes apply to open connections at once.
"""
from __future__ import annotations

import logging
import time

import pytest

from daemon.bus import roles
from daemon.bus.auth import create_keypair, load_keypair, load_public
from daemon.bus.client import Client, ClientTimeout
from daemon.bus.protocol import CommandError
from daemon.ctl.exitcodes import Exit
from daemon.ctl.main import main as ritactl
from fakes.operator import lock_on_robot
from tests.ctl_sim import sim_daemon

MOVE = {"distance_mm": 1.0, "speed_mm_s": 100.0, "confirm": True}


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    rt = tmp_path_factory.mktemp("roles-curve")
    data, laptop = rt / "data", rt / "laptop"
    create_keypair(data / "keys", "server")
    auth = data / "authorized_keys"
    for name, role in (("vic", "viewer"), ("ole", "operator"), ("ada", "admin"), ("rex", "operator")):
        public, _ = create_keypair(laptop, name)
        roles.write_entry(auth, name, load_public(public), role)
    (laptop / "server.key").write_bytes((data / "keys" / "server.key").read_bytes())

    def curve_on(cfg) -> None:
        cfg.daemon.data_dir = str(data)
        for key in ("command_endpoints", "telemetry_endpoints", "frame_endpoints"):
            getattr(cfg.daemon, key).append("tcp://127.0.0.1:0")
        cfg.security.curve = True

    with sim_daemon(rt, curve_on) as d:
        tcp = next(e for e in d.server.endpoints if e.startswith("tcp://"))
        yield {"tcp": tcp, "ipc": d.server.endpoints[0], "laptop": laptop, "auth": auth}


def client(robot: dict, name: str, timeout: float = 10) -> Client:
    public, secret = load_keypair(robot["laptop"] / f"{name}.key_secret")
    server = load_public(robot["laptop"] / "server.key")
    return Client(robot["tcp"], timeout=timeout, curve={"public": public, "secret": secret, "server": server},
                  key_id=name)


def code_of(c: Client, cmd: str, **args) -> tuple[str, str]:
    try:
        c.call(cmd, **args)
        return "ok", ""
    except CommandError as exc:
        return exc.code, exc.args[0]


def test_viewer_watches_but_may_not_move_start_jobs_or_capture(robot):
    with client(robot, "vic") as c, client(robot, "ole") as op:
        assert set(c.call("status")["devices"]) == {"camera", "tracker", "robot"}
        assert "latest" in c.call("state")  # what `ritactl watch` starts from
        sub, frames = c.subscriber(["robot.state"]), c.subscriber(["camera.frame"], frames=True)
        try:
            time.sleep(0.3)  # the subscriptions reach the daemon before anything is published
            op.call("robot.move", **MOVE)  # the operator acts, the viewer watches
            got = sub.recv(5.0)
            assert got is not None and got[0] == "robot.state"
            op.call("camera.stream.start")
            try:
                got = frames.recv(5.0)
            finally:
                op.call("camera.stream.stop")
            assert got is not None and got[0] == "camera.frame"
            assert code_of(c, "camera.stream.start") == (
                "forbidden", "camera.stream.start needs role operator; key vic is viewer")
        finally:
            sub.close()
            frames.close()
        for cmd, args, need in (("robot.move", MOVE, "operator"),
                                ("calib.start", {"procedure": "referencing"}, "operator"),
                                ("capture", {}, "operator"),
                                ("keys.list", {}, "admin")):
            assert code_of(c, cmd, **args) == ("forbidden", f"{cmd} needs role {need}; key vic is viewer")


def test_a_viewer_stops_the_robot_and_only_an_operator_releases_it(robot, caplog):
    """Stopping is never forbidden: the viewer's STOP halts a moving base and latches, logged with its
    name."""
    caplog.set_level(logging.INFO, logger="daemon.ritad")
    with client(robot, "vic") as vic, client(robot, "ole") as ole:
        ole.call("robot.move", distance_mm=300.0, speed_mm_s=2.0, confirm=True, wait=False)  # 150 s of motion
        end = time.monotonic() + 20
        while ole.call("robot.status")["state"] != "MOVING":
            assert time.monotonic() < end
            time.sleep(0.02)
        assert vic.call("robot.stop")["latched"]
        end = time.monotonic() + 5
        while ole.call("robot.status")["state"] != "IDLE":
            assert time.monotonic() < end, "base not idle after a viewer's STOP"
            time.sleep(0.01)
        latch = vic.call("state")["latch"]
        assert latch["latched"] and latch["by"] == "vic (viewer)", latch
        assert code_of(ole, "robot.move", **MOVE)[0] == "stopped"
        assert code_of(vic, "robot.release")[0] == "forbidden"
        assert ole.call("robot.release") == {"released": True, "was_latched": True}
        ole.call("robot.move", **MOVE)
    assert any("robot STOP by vic (viewer)" in r.getMessage() for r in caplog.records)


def test_operator_moves_starts_jobs_captures_but_may_not_change_keys(robot, caplog):
    caplog.set_level(logging.INFO, logger="daemon.ritad.server")
    with client(robot, "ole") as c:
        c.call("robot.move", **MOVE)
        job = c.call("calib.start", procedure="referencing", params={})["job"]
        assert any(j["job"] == job for j in c.call("calib.jobs")["jobs"])
        lock_on_robot(c)  # tracker.aim + tracker.find: motions too
        assert "path" in c.call("capture", label="roles")
        public = c.curve["public"].decode()
        assert code_of(c, "keys.allow", name="x", public_key=public, role="admin") == (
            "forbidden", "keys.allow needs role admin; key ole is operator")
    motion = [r.getMessage() for r in caplog.records if r.getMessage().startswith("motion ")]
    assert [m.split()[1] for m in motion] == ["robot.move", "tracker.aim", "tracker.find"], motion
    assert all(f"from ole ({public}) (role operator)" in m for m in motion), motion
    assert "'distance_mm': 1.0" in motion[0]
    assert not (robot["auth"] / "x.key").exists()


def test_local_ipc_client_is_operator_by_default(robot):
    with Client(robot["ipc"], timeout=10) as c:
        assert code_of(c, "robot.stop") == ("ok", "")
        assert code_of(c, "robot.release") == ("ok", "")
        assert code_of(c, "keys.list")[0] == "forbidden"


def test_admin_manages_keys_and_changes_apply_to_open_connections(robot):
    with client(robot, "ada") as admin, client(robot, "rex") as rex:
        assert {k["name"]: k["role"] for k in admin.call("keys.list")["keys"]}["rex"] == "operator"
        rex.call("robot.stop")
        # no restart: rex's open connection is a viewer now
        admin.call("keys.role", name="rex", role="viewer")
        assert code_of(rex, "robot.release") == ("forbidden",
                                                 "robot.release needs role operator; key rex is viewer")
        assert code_of(rex, "robot.stop") == ("ok", "")  # stopping is never forbidden
        admin.call("robot.release")
        assert rex.call("status")["devices"]
        assert admin.call("keys.revoke", name="rex") == {"revoked": "rex"}
        assert code_of(rex, "status")[0] == "unauthorized"  # the open connection loses access at once
        assert code_of(admin, "keys.role", name="rex", role="admin") == (
            "not_found", f"keys.role: no key named 'rex' in {robot['auth']}")
        assert code_of(admin, "keys.allow", name="rex", public_key="short")[0] == "bad_args"
        assert code_of(admin, "keys.allow", name="rex", public_key=rex.curve["public"].decode(),
                       role="root")[0] == "bad_args"
    with client(robot, "rex", timeout=1.5) as again:  # a new connection is refused by ZAP
        with pytest.raises(ClientTimeout):
            again.call("ping")
    with client(robot, "ada") as admin:  # allowed again, as the default role
        public = load_public(robot["laptop"] / "rex.key").decode()
        assert admin.call("keys.allow", name="rex", public_key=public)["role"] == "viewer"
    with client(robot, "rex") as rex:
        assert rex.call("ping")["pong"] is True


def _ctl(robot: dict, key: str, *argv: str) -> int:
    return ritactl(["--endpoint", robot["tcp"], "--keys", str(robot["laptop"]), "--key", key, *argv])


def test_ritactl_exit_codes_and_keys_over_the_bus(robot, capsys, tmp_path):
    assert _ctl(robot, "vic", "robot", "move", "1", "--yes") == Exit.REFUSED
    err = capsys.readouterr().err
    assert "robot.move needs role operator; key vic is viewer [forbidden]" in err and "Traceback" not in err
    public, _ = create_keypair(tmp_path, "newbie")
    assert _ctl(robot, "ole", "keys", "allow", str(public), "--role", "operator", "--bus") == Exit.REFUSED
    assert "keys.allow needs role admin" in capsys.readouterr().err
    assert _ctl(robot, "ada", "keys", "allow", str(public), "--role", "operator", "--bus") == Exit.OK
    assert "allowed newbie as operator" in capsys.readouterr().out
    assert _ctl(robot, "ada", "keys", "list", "--bus") == Exit.OK
    out = capsys.readouterr().out
    assert any(line.split()[:2] == ["newbie", "operator"] for line in out.splitlines()), out
    assert _ctl(robot, "ada", "keys", "revoke", "--name", "newbie", "--bus") == Exit.OK
    assert not (robot["auth"] / "newbie.key").exists()


def test_ritactl_keys_on_the_robot_files(tmp_path, capsys):
    """Root on the robot: the files, no daemon needed; allow's default role is viewer."""
    public, _ = create_keypair(tmp_path / "laptop", "bob")
    auth = tmp_path / "auth"
    assert ritactl(["keys", "allow", str(public), "--dir", str(auth)]) == Exit.OK
    assert "allowed bob as viewer" in capsys.readouterr().out
    assert ritactl(["keys", "role", "--name", "bob", "--role", "admin", "--dir", str(auth)]) == Exit.OK
    assert ritactl(["keys", "list", "--dir", str(auth)]) == Exit.OK
    assert capsys.readouterr().out.splitlines()[-1].split()[:2] == ["bob", "admin"]
    assert ritactl(["keys", "role", "--name", "bob", "--dir", str(auth)]) == Exit.USAGE
    assert ritactl(["keys", "role", "--name", "carol", "--role", "admin",
                    "--dir", str(auth)]) == Exit.BAD_INPUT
    assert "no key named 'carol'" in capsys.readouterr().err
    assert ritactl(["keys", "allow", str(public), "--role", "root", "--dir", str(auth)]) == Exit.USAGE
