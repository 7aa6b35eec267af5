"""The operator's small annoyances, each fixed and kept fixed: a missing ipc socket fails at once,
a missing extra is named with its exit code, --check-config checks the key files, ritad's
refusals say what to do in ritactl's words."""
from __future__ import annotations

import os
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest

from daemon.bus.auth import CREDENTIAL_NAME, create_keypair
from daemon.ctl import main as ctl
from daemon.ctl.exitcodes import Exit
from daemon.ritad.main import RitadExit
from tests.ritad_up import ritad_in_process

ROOT = Path(__file__).resolve().parents[3]


def python(code: str, *, env: dict[str, str] | None = None, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, cwd=ROOT,
                          env={**os.environ, "PYTHONPATH": str(ROOT), **(env or {})})


def without(modules: tuple[str, ...], argv: list[str]) -> str:
    """ritactl ``argv`` in a Python where ``modules`` cannot be imported (a laptop without the extra)."""
    return (f"import sys\nfor m in {modules!r}: sys.modules[m] = None\n"
            f"from daemon.ctl.main import main\nsys.exit(main({argv!r}))")


def test_a_missing_ipc_socket_fails_at_once(tmp_path, capsys):
    ep = f"ipc://{tmp_path}/run/cmd"
    t0 = time.monotonic()
    # a device verb waits up to 120 s for an answer; a socket file that is not there will never answer
    assert ctl.main(["--endpoint", ep, "--timeout", "60", "robot", "status"]) == Exit.NO_ANSWER
    assert time.monotonic() - t0 < 60  # it did not wait out its 60 s
    err = capsys.readouterr().err
    assert f"{tmp_path}/run/cmd" in err and "does not exist" in err and "Traceback" not in err
    assert "within 60 s" not in err  # the socket check answered, not the timeout (client.py _no_answer)


def test_console_without_aiohttp_is_exit_5_naming_the_extra():
    res = python(without(("aiohttp",), ["--endpoint", "tcp://127.0.0.1:9", "console", "--duration", "1"]))
    assert res.returncode == Exit.BAD_INPUT, res.stderr
    assert "pip install 'rita[console]'" in res.stderr and "aiohttp" in res.stderr and "Traceback" not in res.stderr


@pytest.mark.parametrize("argv", [["plate", "survey", "photos", "--plate", "p.json", "--out", "o.json"],
                                  ["recompute", "dataset"]])
def test_offline_verbs_without_numpy_or_opencv_name_the_laptop_extra(argv):
    res = python(without(("cv2", "numpy"), argv))
    assert res.returncode == Exit.BAD_INPUT, res.stderr
    assert "pip install 'rita[laptop]'" in res.stderr and "Traceback" not in res.stderr


@pytest.fixture(scope="module")
def experiment_dataset(tmp_path_factory) -> Path:
    """An experiment folder from the independent writer (its calibration recomputed from its referencing)."""
    import numpy as np

    from daemon.compute.recompute import recompute
    from tests.dataset_writer import write_experiment, write_referencing

    tmp = tmp_path_factory.mktemp("datasets")
    rob_H_cam = write_referencing(tmp / "ref")
    write_experiment(tmp / "exp", recompute(tmp / "ref")[0], rob_H_cam, np.array([1500.0, 200.0, 3.0]))
    return tmp / "exp"


@pytest.mark.parametrize("blocked", ["matplotlib", "cv2"])
def test_recompute_without_a_package_of_the_extra_writes_nothing(experiment_dataset, tmp_path, blocked):
    """The laptop without the plot's matplotlib (issue 35): exit 5 naming the extra, before --out exists."""
    out = tmp_path / "out"
    res = python(without((blocked,), ["recompute", str(experiment_dataset), "--out", str(out)]))
    assert res.returncode == Exit.BAD_INPUT, res.stderr
    assert "pip install 'rita[laptop]'" in res.stderr and blocked in res.stderr
    assert "Traceback" not in res.stderr
    assert not out.exists()  # no partial report.md / report.csv / result.json


def test_the_laptop_extra_computes_without_the_robots_device_packages():
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    names = {r.split(">")[0].split("=")[0].strip().lower() for r in extras["laptop"]}
    assert {"numpy", "opencv-python-headless", "matplotlib"} <= names  # matplotlib: recompute --out's plot
    assert not names & {"harvesters", "genicam", "pyserial"}
    assert "rita[laptop]" in (ROOT / "docs" / "operations.md").read_text()
    assert "rita[laptop]" in (ROOT / "README.md").read_text()


def _curve_config(tmp_path: Path) -> Path:
    cfg = tmp_path / "ritad.toml"
    text = (ROOT / "systemd" / "ritad.toml").read_text().replace('data_dir = "/var/lib/ritad"',
                                                                  f'data_dir = "{tmp_path / "data"}"')
    cfg.write_text(text)
    return cfg


def test_check_config_names_a_missing_server_key_file(tmp_path):
    cfg = _curve_config(tmp_path)
    from daemon.ritad.config import load
    from daemon.ritad.keycheck import server_key_candidates

    if any(p.exists() for p in server_key_candidates(load(cfg), {})):
        pytest.skip("this machine has an installed ritad unit whose server key exists")
    check = f"import sys\nfrom daemon.ritad.main import main\nsys.exit(main(['--check-config', {str(cfg)!r}]))"
    env = {k: v for k, v in os.environ.items() if k != "CREDENTIALS_DIRECTORY"}
    res = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, timeout=60, cwd=ROOT,
                         env={**env, "PYTHONPATH": str(ROOT)})
    assert res.returncode == RitadExit.CANNOT_START, res.stdout + res.stderr
    assert str(tmp_path / "data" / "keys" / "server.key_secret") in res.stderr and "keys init --server" in res.stderr
    assert "configuration OK" not in res.stdout
    creds = tmp_path / "creds"
    _, secret = create_keypair(creds, "server")
    secret.rename(creds / CREDENTIAL_NAME)
    ok = python(check, env={"CREDENTIALS_DIRECTORY": str(creds)})
    assert ok.returncode == RitadExit.OK and "configuration OK" in ok.stdout, ok.stderr
    assert "authorized_keys_dir" in ok.stdout and "--role operator" in ok.stdout  # not there yet: a warning


def test_an_unconfirmed_motion_tells_the_operator_to_add_yes(tmp_path, capsys):
    with ritad_in_process(tmp_path / "rt", ready=False) as (d, _):
        code = ctl.main(["--endpoint", d.server.endpoints[0], "robot", "move", "10"])
    err = capsys.readouterr().err
    assert code == Exit.REFUSED and "add --yes" in err and "ritactl robot move" in err, err
    assert "=true (ritactl" not in err and "confirm (ritactl" not in err, err
