"""CURVE + ZAP on tcp endpoints: allowed key works, unknown key and plaintext are refused,
revocation takes effect without a restart, ipc stays plain, commands are logged with the key id."""
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from daemon.auth import create_keypair, load_keypair, load_public
from daemon.client import Client, ClientTimeout

ROOT = Path(__file__).resolve().parents[1]

CONFIG = """
[daemon]
command_endpoints = ["ipc://{tmp}/cmd", "tcp://127.0.0.1:0"]
telemetry_endpoints = ["ipc://{tmp}/tel", "tcp://127.0.0.1:0"]
frame_endpoints = ["ipc://{tmp}/frm", "tcp://127.0.0.1:0"]
data_dir = "{tmp}/data"

[devices]
camera = "genicam:///nonexistent/producer.cti"
tracker = "emscon://127.0.0.1:1"
robot = "loop://"

[security]
curve = true
"""


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
    (tmp / "ritad.toml").write_text(CONFIG.format(tmp=tmp))
    log = open(tmp / "ritad.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "daemon.main", "--config", str(tmp / "ritad.toml")], cwd=ROOT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE, stderr=log,
                            text=True)
    line = proc.stdout.readline()
    assert line.startswith("ritad ready"), (line, (tmp / "ritad.log").read_text())
    eps = line.split(": ", 1)[1].split()
    tcp = next(e for e in eps if e.startswith("tcp://"))
    server = load_public(data / "keys" / "server.key")
    yield {"tcp": tcp, "ipc": f"ipc://{tmp}/cmd", "keys": keys, "server": server, "data": data, "log": tmp / "ritad.log"}
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
    time.sleep(0.3)
    assert alice["public"].decode() in secured["log"].read_text()  # audit trail: the key id of who asked


def test_unknown_key_and_plaintext_are_refused(secured):
    mallory = curve(secured["keys"], "mallory", secured["server"])
    with Client(secured["tcp"], timeout=1.0, curve=mallory) as c:
        with pytest.raises(ClientTimeout):
            c.call("ping")
    with Client(secured["tcp"], timeout=1.0) as c:
        with pytest.raises(ClientTimeout):
            c.call("ping")
    assert "refused CURVE client" in secured["log"].read_text()


def test_local_ipc_stays_plain(secured):
    with Client(secured["ipc"], timeout=5) as c:
        assert c.call("ping")["pong"] is True
        assert c.call("hello")["curve_server_key"] == secured["server"].decode()


def test_revocation_without_restart(secured):
    alice = curve(secured["keys"], "alice", secured["server"])
    allowed = secured["data"] / "authorized_keys" / "alice.key"
    r = subprocess.run([sys.executable, "-m", "daemon.ctl", "keys", "revoke", "--name", "alice", "--dir",
                        str(allowed.parent)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    with Client(secured["tcp"], timeout=1.0, curve=alice) as c:
        with pytest.raises(ClientTimeout):
            c.call("ping")
    r = subprocess.run([sys.executable, "-m", "daemon.ctl", "keys", "allow", str(secured["keys"] / "alice.key"),
                        "--name", "alice", "--dir", str(allowed.parent)], cwd=ROOT, capture_output=True, text=True,
                       timeout=60)
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
    from daemon.client import Subscriber

    plain = Subscriber(next(e for e in eps if e.startswith("tcp://")), ["daemon.health"])
    try:
        assert plain.recv(2.5) is None  # a plaintext subscriber gets nothing
    finally:
        plain.close()


def test_missing_server_key_is_a_clear_error(tmp_path):
    (tmp_path / "ritad.toml").write_text(CONFIG.format(tmp=tmp_path))
    r = subprocess.run([sys.executable, "-m", "daemon.main", "--config", str(tmp_path / "ritad.toml")], cwd=ROOT,
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and "ritactl keys init --server" in r.stderr
