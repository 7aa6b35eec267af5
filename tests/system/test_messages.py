"""Messages an operator can act on, and the sim installer's files.

* a port that is not an emScon server (HTTP, SSH) is named as such, with what it sent;
* measure/capture before lock says to aim and find first; find before aim says how;
* ``ritad --sim`` leaves plate, camera model and rough nests in ``data_dir/sim``.
"""
from __future__ import annotations

import json
import socket
import threading
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest

from daemon.ctl import main as ctl
from daemon.bus.client import Client
from daemon.ritad.daemon import Daemon
from daemon.bus.protocol import CommandError
from drivers.base import DeviceLost, DeviceURL
from drivers.emscon.adapter import EmsconTracker
from drivers.emscon.client import EmsconClient
from drivers.emscon.enums import ES_Command
from tests.ritad_up import ritad_in_process


class ForeignServer(threading.Thread):
    """A TCP server speaking something else: sends ``banner`` first, or ``reply`` once it got bytes."""

    def __init__(self, banner: bytes = b"", reply: bytes = b"") -> None:
        super().__init__(daemon=True)
        self.banner, self.reply = banner, reply
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.sock.settimeout(10)
        self.port = self.sock.getsockname()[1]
        self.start()

    def run(self) -> None:
        try:
            while True:
                conn, _ = self.sock.accept()
                with conn:
                    conn.settimeout(5)
                    if self.banner:
                        conn.sendall(self.banner)
                    if self.reply and conn.recv(4096):
                        conn.sendall(self.reply)
                    conn.recv(4096)  # until the client hangs up
        except OSError:
            return  # closed by the test


@pytest.mark.parametrize("server, sent", [
    (dict(reply=b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n"), "HTTP/1."),
    (dict(banner=b"SSH-2.0-OpenSSH_9.2p1\r\n"), "SSH-2.0"),
    (dict(reply=b"\x00\x01\x02\x03\xff\xfe\xfd\xfc"), "\\x00\\x01\\x02\\x03\\xff\\xfe\\xfd"),
])
def test_a_port_that_does_not_speak_emscon_is_named(server: dict, sent: str) -> None:
    srv = ForeignServer(**server)
    try:
        c = EmsconClient("127.0.0.1", srv.port, timeout=5)
        c.connect()
        with pytest.raises(DeviceLost) as ei:
            c.request(ES_Command.GetSystemStatus)
        want = f"the peer at 127.0.0.1:{srv.port} does not speak emScon (it sent '{sent}')"
        assert want in str(ei.value), str(ei.value)
        assert "lPacketSize 1347703880" not in str(ei.value).split("(protocol error")[0]
        t = EmsconTracker(DeviceURL.parse(f"emscon://127.0.0.1:{srv.port}?timeout=5"))
        with pytest.raises(DeviceLost, match="does not speak emScon"):
            t.open()  # what the runner shows as the FAULT reason
    finally:
        srv.sock.close()


@pytest.fixture
def sim(tmp_path: Path) -> Iterator[tuple[Daemon, Client]]:
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", timeout=30, client_timeout=20) as (d, c):
        yield d, c


def test_measure_and_capture_before_lock_say_aim_and_find_first(sim, capsys) -> None:
    d, c = sim
    hint = "aim and find first: `ritactl tracker aim X Y Z` then `ritactl tracker find`"
    for cmd in ("tracker.measure", "capture", "tracker.stream.start"):
        with pytest.raises(CommandError) as ei:
            c.call(cmd)
        assert ei.value.code == "tracker_MeasurementStatusNotReady", cmd  # the stable code stays
        assert hint in ei.value.args[0] and "10004" not in ei.value.args[0], ei.value.args[0]
    with pytest.raises(CommandError) as ei:
        c.call("tracker.find")
    assert ei.value.code == "bad_args"
    assert "ritactl tracker aim X Y Z" in ei.value.args[0] and "--distance" in ei.value.args[0]
    assert "approx_distance_mm" not in ei.value.args[0]
    c.call("tracker.aim", x=1000.0, y=1000.0, z=1000.0)  # nothing there
    with pytest.raises(CommandError) as ei:
        c.call("tracker.find")
    assert ei.value.code == "tracker_ModuleTimedOut" and "aim closer" in ei.value.args[0], ei.value.args[0]
    assert ctl.main(["--endpoint", d.server.endpoints[0], "capture", "--label", "early"]) != 0
    assert hint in capsys.readouterr().err


def test_sim_installs_plate_design_board_and_rough_nests(sim) -> None:
    """The installer's files are what an operator has before measuring: no camera model (the
    intrinsics make it), the plate's design (the survey measures it), rough nest positions."""
    d, c = sim
    folder = Path(d.config.daemon.data_dir) / "sim"
    files = {p.name: json.loads(p.read_text()) for p in folder.glob("*.json")}
    assert sorted(files) == ["board.json", "nests.json", "plate.json"]
    truth = c.call("sim.truth")  # scores the installer's files, never feeds the product
    assert files["plate.json"] == truth["plate"]
    trk_H_abs = np.linalg.inv(np.array(truth["abs_H_trk"]))
    for name, p_abs in truth["nests_abs"].items():
        p_trk = trk_H_abs[:3, :3] @ p_abs + trk_H_abs[:3, 3]
        off = np.linalg.norm(np.array(files["nests.json"][name]) - p_trk)
        assert 0.05 < off < 15.0, (name, off)  # rough (a few mm off), but well inside the search radius
    listed = {f["path"] for f in c.call("files.list", path="sim")["files"]}
    assert listed == {"sim/board.json", "sim/nests.json", "sim/plate.json"}
