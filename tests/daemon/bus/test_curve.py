"""CURVE + ZAP on tcp endpoints: allowed key works, unknown key and plaintext are refused,
revocation takes effect without a restart, ipc stays plain, commands are logged with the key id."""
import os
import signal
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from daemon.bus.auth import create_keypair, load_keypair, load_public
from daemon.bus.client import Client, ClientRefused, ClientTimeout
from daemon.bus.protocol import CommandError
from tools.harness.config import NO_DEVICES, ipc_command, ritad_toml

ROOT = Path(__file__).resolve().parents[3]


def curve_config(tmp: Path) -> str:
    """ritad without devices, CURVE on tcp, plain ipc in ``tmp``."""
    return ritad_toml(ipc_dir=tmp, data=tmp / "data", devices=NO_DEVICES, tcp=True, curve=True)


@pytest.fixture(scope="module")
def secured(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("curve")
    data = tmp / "data"
    create_keypair(data / "keys", "server")
    keys = tmp / "clients"
    for name in ("alice", "mallory"):
        create_keypair(keys, name)
    (data / "authorized_keys").mkdir(parents=True)
    (data / "authorized_keys" / "alice.key").write_bytes((keys / "alice.key").read_bytes())
    (tmp / "ritad.toml").write_text(curve_config(tmp))
    log = open(tmp / "ritad.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "daemon.ritad.main", "--config", str(tmp / "ritad.toml")],
                            cwd=ROOT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE, stderr=log,
                            text=True)
    line = proc.stdout.readline()
    assert line.startswith("ritad ready"), (line, (tmp / "ritad.log").read_text())
    eps = line.split(": ", 1)[1].split()
    tcp = next(e for e in eps if e.startswith("tcp://"))
    server = load_public(data / "keys" / "server.key")
    yield {"tcp": tcp, "ipc": ipc_command(tmp), "keys": keys, "server": server, "data": data,
           "log": tmp / "ritad.log"}
    proc.send_signal(signal.SIGTERM)
    proc.wait(10)


def curve(keys: Path, name: str, server: bytes) -> dict:
    public, secret = load_keypair(keys / f"{name}.key_secret")
    return {"public": public, "secret": secret, "server": server}


def test_secret_files_are_private(secured):
    for f in (secured["data"] / "keys" / "server.key_secret", secured["keys"] / "alice.key_secret"):
        assert stat.S_IMODE(f.stat().st_mode) == 0o600


def test_allowed_key_works_and_is_logged(secured):
    alice = curve(secured["keys"], "alice", secured["server"])
    with Client(secured["tcp"], timeout=5, curve=alice) as c:
        assert c.call("ping")["pong"] is True
        assert "help" in c.call("help")["commands"]
        # alice is a viewer: reads log at DEBUG, a refused motion at WARNING
        with pytest.raises(CommandError):
            c.call("robot.move", distance_mm=1.0, confirm=True)
    wait_for_log(secured["log"], alice["public"].decode(), 30)  # audit trail: the key id of who asked


def test_unknown_key_is_refused_and_logged(secured):
    mallory = curve(secured["keys"], "mallory", secured["server"])
    with Client(secured["tcp"], timeout=5.0, curve=mallory, key_id="mallory") as c:
        # ClientRefused comes only from the socket's handshake report (ZAP), never from the 5 s deadline,
        # which raises a plain ClientTimeout "no answer" (client.py); its latency: bench/bench_refusal.py
        with pytest.raises(ClientRefused) as e:
            c.call("ping")
    assert str(e.value).startswith("refused: key mallory is not allowed by the daemon")
    assert "--role operator" in str(e.value)  # the hint is the whole command to run on the robot
    assert isinstance(e.value, ClientTimeout)  # existing handlers map it to exit 3
    log = wait_for_log(secured["log"],
                       f"refused CURVE key {mallory['public'].decode()} client from 127.0.0.1")
    assert "unknown key" in log


def test_plaintext_attempt_is_refused_and_logged(secured):
    # a remote client's greeting arrives after the accept: its address is logged
    host, port = secured["tcp"][len("tcp://"):].rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=5) as raw:
        time.sleep(1.0)  # network latency, as from a laptop (and time for a busy daemon)
        raw.sendall(b"\xff" + bytes(8) + b"\x7f" + bytes([3, 0]) + b"NULL".ljust(20, b"\0") + bytes(32))
        raw.settimeout(5)
        try:
            while raw.recv(100):
                pass
        except OSError:
            pass
        local = "%s:%d" % raw.getsockname()[:2]
    line = wait_for_log(secured["log"], f"refused plaintext client from {local}")
    assert "requires CURVE" in line
    # ritactl without keys is told at once (its repeat is counted into the next log line)
    with Client(secured["tcp"], timeout=5.0) as c:
        with pytest.raises(ClientRefused) as e:  # the refusal, not the deadline (bench/bench_refusal.py)
            c.call("ping")
    assert "requires CURVE keys" in str(e.value)


def test_refusal_log_counts_repeats(caplog):
    from daemon.bus.auth import RefusalLog

    r = RefusalLog(window_s=0.2)
    with caplog.at_level("WARNING", logger="daemon.bus.auth"):
        for port in range(5):
            r.refused("plaintext", f"10.0.0.7:{4000 + port}", "needs CURVE")
        r.refused("plaintext", "10.0.0.8:4000", "needs CURVE")
        time.sleep(0.25)
        r.refused("plaintext", "10.0.0.7:4100", "needs CURVE")
    lines = [rec.getMessage() for rec in caplog.records]
    assert lines == ["refused plaintext client from 10.0.0.7:4000: needs CURVE",
                     "refused plaintext client from 10.0.0.8:4000: needs CURVE",
                     "refused plaintext client from 10.0.0.7:4100: needs CURVE "
                     "(4 more attempt(s) in the last 0.2 s)"]
    assert r.count == 7


def test_silent_refusal_times_out_with_the_key_id():
    """A peer that accepts and says nothing (no handshake signal at all): the message names both causes."""
    import zmq

    silent = socket.create_server(("127.0.0.1", 0))
    try:
        pub, sec = zmq.curve_keypair()
        srv, _ = zmq.curve_keypair()
        endpoint = "tcp://127.0.0.1:%d" % silent.getsockname()[1]
        with Client(endpoint, timeout=0.5, curve={"public": pub, "secret": sec, "server": srv},
                    key_id="bob") as c:
            with pytest.raises(ClientTimeout) as e:
                c.call("ping")
        assert not isinstance(e.value, ClientRefused)
        assert str(e.value).startswith("no answer: the daemon is down, or it refused this key (bob)")
    finally:
        silent.close()


def wait_for_log(path: Path, text: str, timeout: float = 5.0) -> str:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        lines = [ln for ln in path.read_text().splitlines() if text in ln]
        if lines:
            return lines[-1]
        time.sleep(0.05)
    raise AssertionError(f"{text!r} not logged:\n{path.read_text()[-2000:]}")


def test_local_ipc_stays_plain(secured):
    with Client(secured["ipc"], timeout=5) as c:
        assert c.call("ping")["pong"] is True
        assert c.call("hello")["curve_server_key"] == secured["server"].decode()


def test_revocation_without_restart(secured):
    alice = curve(secured["keys"], "alice", secured["server"])
    allowed = secured["data"] / "authorized_keys" / "alice.key"
    r = subprocess.run([sys.executable, "-m", "daemon.ctl.main", "keys", "revoke", "--name", "alice", "--dir",
                        str(allowed.parent)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    with Client(secured["tcp"], timeout=1.0, curve=alice) as c:
        with pytest.raises(ClientTimeout):
            c.call("ping")
    r = subprocess.run([sys.executable, "-m", "daemon.ctl.main", "keys", "allow",
                        str(secured["keys"] / "alice.key"), "--name", "alice", "--dir", str(allowed.parent)],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    with Client(secured["tcp"], timeout=5, curve=alice) as c:
        assert c.call("ping")["pong"] is True


def test_telemetry_over_curve(secured):
    alice = curve(secured["keys"], "alice", secured["server"])
    with Client(secured["tcp"], timeout=5, curve=alice) as c:
        sub = c.subscriber(["daemon.health"])
        try:
            msg = sub.recv(5.0)
            assert msg is not None and msg[0] == "daemon.health"
        finally:
            sub.close()
    with Client(secured["tcp"], timeout=5, curve=alice) as c:
        eps = c.call("hello")["telemetry_endpoints"]
    from daemon.bus.client import Subscriber

    plain = Subscriber(next(e for e in eps if e.startswith("tcp://")), ["daemon.health"])
    try:
        assert plain.recv(2.5) is None  # a plaintext subscriber gets nothing
    finally:
        plain.close()


def test_missing_server_key_is_a_clear_error(tmp_path):
    (tmp_path / "ritad.toml").write_text(curve_config(tmp_path))
    r = subprocess.run([sys.executable, "-m", "daemon.ritad.main", "--config", str(tmp_path / "ritad.toml")],
                       cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 1 and "ritactl keys init --server" in r.stderr


def test_key_selected_by_name_end_to_end(secured, tmp_path):
    """`keys init --name bob` on the laptop, `keys allow` on the robot, key = "bob" in ritactl.toml."""
    from daemon.ctl.keys import resolve_connection

    laptop = tmp_path / "laptop"
    ctl = [sys.executable, "-m", "daemon.ctl.main", "keys"]
    r = subprocess.run([*ctl, "init", "--name", "bob", "--dir", str(laptop)], cwd=ROOT, capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0 and "--key bob" in r.stdout, r
    (laptop / "server.key").write_bytes((secured["data"] / "keys" / "server.key").read_bytes())
    (laptop / "ritactl.toml").write_text(f'endpoint = "{secured["tcp"]}"\n'
                                         f'key = "bob"\nkeys_dir = "{laptop}"\n')
    conn = resolve_connection(config_path=laptop / "ritactl.toml")
    with Client(conn["endpoint"], timeout=5, curve=(conn["curve"], conn["key_id"])) as c:
        with pytest.raises(ClientRefused, match=r"refused: key bob \("):  # not allowed yet
            c.call("ping")
    r = subprocess.run([*ctl, "allow", str(laptop / "bob.key"),
                        "--dir", str(secured["data"] / "authorized_keys")],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    with Client(conn["endpoint"], timeout=5, curve=(conn["curve"], conn["key_id"])) as c:
        assert c.call("ping")["pong"] is True
    # a name with no key file is an error naming the file, never a plaintext attempt
    with pytest.raises(ValueError, match="carol.key_secret does not exist"):
        resolve_connection(key="carol", config_path=laptop / "ritactl.toml")


def test_wrong_server_key_is_named(secured):
    import zmq

    alice = {**curve(secured["keys"], "alice", secured["server"]), "server": zmq.curve_keypair()[0]}
    with Client(secured["tcp"], timeout=5, curve=alice, key_id="alice") as c:
        with pytest.raises(ClientRefused, match="dropped the CURVE handshake.*server.key"):
            c.call("ping")  # the handshake's failure, not the deadline (bench/bench_refusal.py)
