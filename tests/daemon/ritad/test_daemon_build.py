"""Daemon(config) builds and binds at once; a build that fails undoes what it built (the CLI then exits
``cannot start``), so nothing stays bound and the same endpoints can be used again."""
from __future__ import annotations

import socket

import pytest
import zmq

from daemon.ritad import config
from daemon.ritad.daemon import Daemon


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_a_failed_build_leaves_nothing_bound(tmp_path):
    cfg = config.sim_config(tmp_path / "rt", tmp_path / "data")
    cfg.daemon.start_worker = False
    cfg.security.insecure_tcp = True
    telemetry = f"tcp://127.0.0.1:{_free_port()}"
    ctx = zmq.Context()
    taken = ctx.socket(zmq.PUB)
    taken.setsockopt(zmq.LINGER, 0)
    frames_port = taken.bind_to_random_port("tcp://127.0.0.1")
    cfg.daemon.telemetry_endpoints = [telemetry]
    cfg.daemon.frame_endpoints = [f"tcp://127.0.0.1:{frames_port}"]
    try:
        with pytest.raises(zmq.ZMQError):
            Daemon(cfg)  # telemetry bound, then the frames' port is in use
        again = ctx.socket(zmq.PUB)
        again.setsockopt(zmq.LINGER, 0)
        again.bind(telemetry)  # the failed build released it
        again.close()
    finally:
        taken.close()
        ctx.term()
    taken_free = f"tcp://127.0.0.1:{frames_port}"
    cfg.daemon.frame_endpoints = [taken_free]
    d = Daemon(cfg)  # built, not started: stop() still closes every socket
    d.stop()
