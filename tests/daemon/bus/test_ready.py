"""``Client.wait_ready``, the one definition of "devices READY", and the fakes' ritad launcher."""
from __future__ import annotations

import time
from pathlib import Path

import pytest

from daemon.bus.client import Client, ClientTimeout
from tests.ritad_up import ritad_in_process

pytestmark = pytest.mark.timeout(120)


def test_waits_for_the_named_devices_and_names_the_ones_not_ready(tmp_path: Path) -> None:
    # port 1 refuses: the tracker stays in reconnect backoff, never READY
    with ritad_in_process(tmp_path / "rt", ready=False, tracker="emscon://127.0.0.1:1?connect_timeout=0.5") \
            as (d, c):
        h = c.wait_ready(["camera", "robot"], timeout=60)
        assert h["devices"]["camera"]["state"] == h["devices"]["robot"]["state"] == "READY"
        assert h["devices"]["tracker"]["state"] != "READY"
        t0 = time.monotonic()
        with pytest.raises(ClientTimeout) as err:  # 3 s: a loaded machine's daemon answers within it
            c.wait_ready(timeout=3.0)
        assert time.monotonic() - t0 >= 3.0  # its own deadline ended it (named below)
        assert "devices not READY within 3 s" in str(err.value) and "'tracker'" in str(err.value)
        with pytest.raises(ClientTimeout, match="worker"):  # no worker runs here
            c.wait_ready(["camera"], timeout=0.5, worker=True)


def test_no_daemon_is_a_bounded_timeout_and_a_dead_process_ends_the_wait_early(tmp_path: Path) -> None:
    with Client(f"ipc://{tmp_path}/nobody", timeout=1) as c:
        t0 = time.monotonic()
        with pytest.raises(ClientTimeout, match=r"not READY within 0.6 s .*: no answer"):
            c.wait_ready(timeout=0.6)  # its own 0.6 s ended it, not the client's 1 s per call
        assert time.monotonic() - t0 >= 0.6
        with pytest.raises(ClientTimeout, match="went away"):
            c.wait_ready(timeout=30, alive=lambda: False)


def test_start_ritad_with_fakes_then_devices_ready(tmp_path: Path) -> None:
    from fakes.launch import start_ritad

    with start_ritad(tmp=tmp_path, timeout=60) as r:
        assert r.endpoint == f"ipc://{tmp_path}/rt/cmd" and r.ready_s > 0
        h = r.wait_ready(timeout=90)
        assert all(v["state"] == "READY" for v in h["devices"].values())
        assert sorted(p.name for p in (tmp_path / "data" / "sim").iterdir()) == \
            ["board.json", "nests.json", "plate.json"]  # the world's factory played the installer
        with r.client() as c:
            assert c.call("hello")["sim"] is True
    assert r.proc.returncode == 0  # SIGTERM: a clean stop
