"""The shipped example config (systemd/ritad.toml) as a robot would run it, on the fakes.

A test copy changes only what cannot be the same on a test machine: paths (/run/ritad,
/var/lib/ritad) go to a temp dir, the tcp ports bind 127.0.0.1 port 0, and the device
URLs become ``sim:`` (the fakes that speak each device's protocol). Everything else
is the file as shipped: the worker it starts completes a referencing job, and its
tcp endpoint refuses a client without keys, so that client cannot move the robot.
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from daemon.bus.auth import create_keypair, load_keypair, load_public
from daemon.bus.client import Client, ClientTimeout
from fakes.demo import operator_files
from fakes.board import run_intrinsics
from tests.system.test_worker_e2e import referencing_params, run_job

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "systemd" / "ritad.toml"
pytestmark = pytest.mark.slow


def example_copy(tmp: Path) -> str:
    """The example with paths, ports and device URLs replaced; each replacement must apply."""
    text = EXAMPLE.read_text()
    subs = [(r'"ipc:///run/ritad/', f'"ipc://{tmp}/rt/'), (r'"/var/lib/ritad"', f'"{tmp}/data"'),
            (r'"tcp://0\.0\.0\.0:\d+"', '"tcp://127.0.0.1:0"'),
            (r'(?m)^(camera|tracker|robot) = "[^"]*"', r'\1 = "sim:"')]
    for pattern, repl in subs:
        text, n = re.subn(pattern, repl, text)
        assert n >= 1, f"the example config no longer contains {pattern}"
    return text


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("example")
    data = tmp / "data"
    create_keypair(data / "keys", "server")  # the install step of docs/operations.md (Keys)
    create_keypair(tmp / "clients", "alice")
    (data / "authorized_keys").mkdir(parents=True)
    (data / "authorized_keys" / "alice.key").write_bytes((tmp / "clients" / "alice.key").read_bytes())
    (tmp / "ritad.toml").write_text(example_copy(tmp))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("CREDENTIALS_DIRECTORY", None)
    log = open(tmp / "ritad.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "daemon.ritad.main", "--config", str(tmp / "ritad.toml")],
                            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=log, text=True)
    line = proc.stdout.readline()
    assert line.startswith("ritad ready"), (line, (tmp / "ritad.log").read_text()[-3000:])
    tcp = next(e for e in line.split(": ", 1)[1].split() if e.startswith("tcp://"))
    c = Client(f"ipc://{tmp}/rt/cmd", timeout=10)
    c.wait_ready(timeout=120, worker=True)  # the example config starts the worker
    alice_pub, alice_sec = load_keypair(tmp / "clients" / "alice.key_secret")
    alice = {"public": alice_pub, "secret": alice_sec, "server": load_public(data / "keys" / "server.key")}
    yield {"c": c, "tmp": tmp, "tcp": tcp, "alice": alice}
    c.close()
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(15)
    except subprocess.TimeoutExpired:
        proc.kill()
    log.close()


def test_keyless_tcp_client_cannot_move_the_robot(example):
    c, tcp = example["c"], example["tcp"]
    before = np.array(c.call("sim.truth")["abs_H_rob"])
    with Client(tcp, timeout=3) as keyless:
        with pytest.raises(ClientTimeout):
            keyless.call("robot.move", distance_mm=50.0, speed_mm_s=100.0, confirm=True)
    with Client(tcp, timeout=10, curve=example["alice"]) as alice:  # the port is live: an allowed key works
        assert alice.call("ping")["pong"] is True
    time.sleep(0.5)
    assert np.array_equal(np.array(c.call("sim.truth")["abs_H_rob"]), before)


def test_example_config_completes_a_referencing_job(example):
    c, tmp = example["c"], example["tmp"]
    board = json.loads(operator_files(c, tmp)["board"].read_text())
    # installs the camera model
    assert run_intrinsics(c, {"board": board}, seed=1, timeout=300)["verdict"] == "ok"
    result = run_job(c, "referencing", referencing_params(c, tmp), timeout=400)
    assert result["verdict"] in ("ok", "warn"), result
    assert c.call("calib.results")["active"]["job"] == result["job"]
    assert Path(result["dataset"], "result.yaml").exists()


def test_example_config_refuses_plaintext_tcp(tmp_path):
    """The same file with CURVE off does not start: tcp without CURVE is a config error (exit 2)."""
    text = example_copy(tmp_path).replace("curve = true", "curve = false")
    (tmp_path / "plain.toml").write_text(text)
    res = subprocess.run([sys.executable, "-m", "daemon.ritad.main",
                          "--config", str(tmp_path / "plain.toml")],
                         cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 2 and "daemon.command_endpoints" in res.stderr and "without CURVE" in res.stderr
    assert not (tmp_path / "rt").exists()
