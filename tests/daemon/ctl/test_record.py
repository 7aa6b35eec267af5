"""ritactl record / replay: a sim session to MCAP and back onto a bus endpoint.

The live test records two seconds of a sim ritad (tracker streaming at 1 kHz, small frames),
checks the file with the mcap library's own reader (CRCs, summary, every tracker packet with no
gap in its seq), then replays it as fast as possible into a subscriber and into
``ritactl watch --json``, which must see the same messages in the same order.
"""
from __future__ import annotations

import io
import json
import math
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import pytest
from mcap.reader import make_reader
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory

from daemon.bus.client import Client
from daemon.bus.protocol import CommandError
from daemon.console.bridge import Bridge
from daemon.ctl import main as ctl
from daemon.ctl import mcapfile as fmt
from daemon.ctl.exitcodes import CtlError, Exit
from daemon.ctl.record import Recorder, check_out, parse_frames
from daemon.ctl.replay import DERIVED, ReplayServer, endpoints, play
from daemon.ritad.daemon import Daemon
from fakes.operator import lock_on_robot
from tests.ritad_up import SMALL_CAMERA, ritad_in_process


def test_frames_option_and_out_file_errors_name_the_value(tmp_path: Path) -> None:
    assert parse_frames(["off"]) == 0 and parse_frames(["every", "3"]) == 3
    for bad in (["every", "0"], ["every"], ["sometimes"], ["every", "x"]):
        with pytest.raises(CtlError) as e:
            parse_frames(bad)
        assert e.value.exit == Exit.USAGE and " ".join(bad) in e.value.args[0]
    with pytest.raises(CtlError, match="nowhere.*does not exist"):
        check_out(tmp_path / "nowhere" / "a.mcap", False)
    (tmp_path / "a.mcap").write_bytes(b"x")
    with pytest.raises(CtlError, match="a.mcap exists"):
        check_out(tmp_path / "a.mcap", False)
    assert check_out(tmp_path / "a.mcap", True) == tmp_path / "a.mcap"
    with pytest.raises(CtlError, match="is a folder"):
        check_out(tmp_path, True)
    with pytest.raises(CtlError, match="'tcp://10.0.0.5:5555'"):
        endpoints("tcp://10.0.0.5:5555")  # a replay serves this computer only


def test_ctl_exit_codes_for_bad_record_and_replay_input(tmp_path: Path, capsys) -> None:
    assert ctl.main(["replay", str(tmp_path / "missing.mcap")]) == Exit.BAD_INPUT
    assert "missing.mcap: no such file" in capsys.readouterr().err
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    assert ctl.main(["replay", "--no-wait", "--endpoint", f"ipc://{tmp_path}/cmd", str(tmp_path / "junk.mcap")]) \
        == Exit.BAD_INPUT
    assert "junk.mcap is not a readable MCAP recording" in capsys.readouterr().err
    (tmp_path / "short.mcap").write_bytes(b"\x89MCAP0\r\n\x01")  # a copy cut short
    # endpoints of their own: the last replay's sockets may still be closing (zmq's IO thread, under
    # load), and a socket something listens on is refused
    (tmp_path / "b").mkdir()
    short = ["replay", "--no-wait", "--endpoint", f"ipc://{tmp_path}/b/cmd", str(tmp_path / "short.mcap")]
    assert ctl.main(short) == Exit.BAD_INPUT
    assert "short.mcap is not a readable MCAP recording" in capsys.readouterr().err
    assert ctl.main(["replay", "--speed", "-1", str(tmp_path / "junk.mcap")]) == Exit.USAGE
    assert ctl.main(["--endpoint", f"ipc://{tmp_path}/none", "record", "--out", "x.mcap",
                     "--frames", "every", "0"]) == Exit.USAGE
    assert ctl.main(["--endpoint", f"ipc://{tmp_path}/none", "record", "--out", "x.mcap",
                     "--duration", "0"]) == Exit.USAGE
    assert "--duration must be more than 0 seconds, got 0" in capsys.readouterr().err


def ros2_raw_image(data: bytes) -> Any:
    schema = Schema(id=1, name=fmt.RAW_IMAGE_SCHEMA, encoding="ros2msg", data=fmt.RAW_IMAGE_ROS2MSG.encode())
    decode = DecoderFactory().decoder_for("cdr", schema)
    assert decode is not None
    return decode(data)


def test_json_and_raw_image_encodings() -> None:
    assert fmt.to_json({"a": math.nan, "b": [1.5, math.inf], "c": b"\x00\x01"}) == b'{"a":null,"b":[1.5,null],"c":"AAE="}'
    header = {"seq": 3, "pixel_format": "Mono8", "shape": [2, 3], "dtype": "|u1", "host_time_ns": 5_000_000_123}
    img = ros2_raw_image(fmt.raw_image(header, bytes(range(6))))  # a ROS 2 decoder reads our CDR
    assert (img.timestamp.sec, img.timestamp.nanosec, img.frame_id) == (5, 123, "camera")
    assert (img.width, img.height, img.step, img.encoding) == (3, 2, 3, "mono8") and img.data == bytes(range(6))
    assert fmt.pixels_of(fmt.raw_image(header, bytes(range(6)))) == bytes(range(6))
    odd = {**header, "pixel_format": "BayerRG8", "shape": [1, 5]}  # strings and data off the 4-byte grid
    img = ros2_raw_image(fmt.raw_image(odd, b"abcde"))
    assert (img.encoding, img.data, img.step) == ("bayer_rggb8", b"abcde", 5) and fmt.pixels_of(
        fmt.raw_image(odd, b"abcde")) == b"abcde"
    assert fmt.raw_image_encoding({"pixel_format": "Mono12", "dtype": "<u2", "shape": [2, 2]}) == "mono16"
    assert fmt.raw_image_encoding({"pixel_format": "X", "dtype": "|u1", "shape": [2, 2, 3]}) == "rgb8"
    with pytest.raises(fmt.UnsupportedFrame, match="Odd16"):
        fmt.raw_image_encoding({"pixel_format": "Odd16", "dtype": ">u2", "shape": [2, 2]})  # big-endian
    schema = fmt.infer_schema("robot.state", {"x_mm": 1, "state": "IDLE", "ok": True, "roll_deg": None})
    assert schema["properties"]["x_mm"] == {"type": "number"} and schema["properties"]["ok"] == {"type": "boolean"}


def test_recorder_gaps_and_replay_order_without_a_daemon(tmp_path: Path) -> None:
    buf = io.BytesIO()
    rec = Recorder(buf, {"test": "1"}, "lz4")
    for seq in (1, 2, 3, 6, 7):  # 4 and 5 never arrived
        rec.telemetry("tracker.point", {"seq": seq, "t_ns": 1000 + seq, "data": {"n": 1, "seq": seq}}, 2000 + seq)
    rec.finish()
    assert rec.counts.missed == 2 and rec.counts.messages == 5
    got = [(ch.topic, m.sequence, m.log_time, m.publish_time) for _, ch, m in
           make_reader(io.BytesIO(buf.getvalue()), validate_crcs=True).iter_messages()]
    # the MCAP sequence counts the channel's messages; the bus seq's gap is in the count of missed ones
    assert got == [("/tracker/point", n, 1000 + s, 2000 + s) for n, s in enumerate((1, 2, 3, 6, 7), start=1)]


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Iterator[tuple[Daemon, Client, str, Path]]:
    tmp = tmp_path_factory.mktemp("record")
    with ritad_in_process(tmp / "rt", tmp / "data", timeout=30, camera=SMALL_CAMERA + "&fps=10") as (d, c):
        lock_on_robot(c)
        c.call("tracker.stream.start", rate_hz=1000.0)
        c.call("camera.stream.start")
        try:
            out = tmp / "session.mcap"
            ep = d.server.endpoints[0]
            assert ctl.main(["--endpoint", ep, "record", "--out", str(out), "--duration", "2",
                             "--frames", "every", "2"]) == Exit.OK
            yield d, c, ep, out
        finally:
            c.call("tracker.stream.stop")
            c.call("camera.stream.stop")


def _read(path: Path) -> list[tuple[str, Any, Any]]:
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        # channels by the bus topic they record (/robot/state: robot.state)
        msgs = [(fmt.bus_topic(ch.topic), sch, m)
                for sch, ch, m in reader.iter_messages(log_time_order=False)]
        assert summary.statistics.message_count == len(msgs)
        meta = {md.name: md.metadata for md in reader.iter_metadata()}
        assert json.loads(meta[fmt.METADATA_NAME]["hello"])["version"]
        # auto: frames in the file, no compression (docs/operations.md); telemetry alone: zstd
        assert meta[fmt.METADATA_NAME]["compression"] == ("none" if "every" in meta[fmt.METADATA_NAME]["frames"]
                                                          else "zstd")
    return msgs


def test_recording_is_a_valid_mcap_with_every_tracker_packet(session, capsys) -> None:
    _, _, _, out = session
    assert not list(out.parent.glob(".*.partial"))  # renamed into place, nothing left behind
    msgs = _read(out)
    points = [json.loads(m.data) for t, _, m in msgs if t == "tracker.point"]
    assert sum(p["n"] for p in points) >= 1000  # 2 s at 1 kHz, in packets
    # a packet's seq is its first record's: each packet starts where the one before ended
    gaps = [(a["seq"], a["n"], b["seq"]) for a, b in zip(points, points[1:]) if a["seq"] + a["n"] != b["seq"]]
    assert not gaps, f"tracker records missing: {gaps[:3]}"
    with open(out, "rb") as f:
        end = {m.name: m.metadata for m in make_reader(f).iter_metadata()}[fmt.END_METADATA_NAME]
    assert end["telemetry_missed"] == "0" and end["ended"] == "duration"  # no telemetry lost either
    for topic in {t for t, _, _ in msgs}:  # each channel counts its own messages, from 1
        seqs = [m.sequence for t, _, m in msgs if t == topic]
        assert seqs == list(range(1, 1 + len(seqs))), topic
    frames = [(sch, ros2_raw_image(m.data)) for t, sch, m in msgs if t == fmt.FRAME_TOPIC]
    headers = [json.loads(m.data) for t, _, m in msgs if t == fmt.FRAME_HEADER_TOPIC]
    seqs = [h["seq"] for h in headers]
    assert len(frames) == len(headers) >= 4 and all(b - a >= 2 for a, b in zip(seqs, seqs[1:]))  # every 2
    assert all(sch.name == "foxglove_msgs/msg/RawImage" and sch.encoding == "ros2msg" for sch, _ in frames)
    assert all((f.height, f.width) == tuple(h["shape"]) and len(f.data) == f.step * f.height
               for (_, f), h in zip(frames, headers))
    assert all(m.publish_time >= m.log_time - int(1e9) for _, _, m in msgs)  # received after (clocks: one host)


def _replay_thread(path: Path, cmd: str, speed: float | None,
                   frames: bool = False) -> tuple[threading.Thread, ReplayServer]:
    server = ReplayServer(cmd, str(path))

    def run() -> None:
        end = time.monotonic() + 20
        with open(path, "rb") as f:
            while (server.subscribers == 0 or frames and server.frame_subscribers == 0) and time.monotonic() < end:
                server.serve(0.05)
            play(server, f, speed)
            server.serve(0.5)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t, server


def _bus(msgs: list[Any]) -> list[Any]:
    """The messages of ritad's own channels: the Foxglove poses derived from them are not replayed."""
    return [(t, sch, m) for t, sch, m in msgs if fmt.mcap_topic(t) not in DERIVED]


def test_replay_feeds_a_subscriber_the_same_messages_in_order(session, tmp_path: Path) -> None:
    _, _, _, out = session
    recorded = [(t, n, fmt.restore_nulls(json.loads(m.data), json.loads(sch.data))) for n, (t, sch, m) in
                enumerate(((t, sch, m) for t, sch, m in _bus(_read(out)) if not t.startswith("camera.")),
                          start=1)]
    t, server = _replay_thread(out, f"ipc://{tmp_path}/cmd", None)
    try:
        c = Client(f"ipc://{tmp_path}/cmd", timeout=5)
        sub = c.subscriber(hwm=100_000)
        got = []
        for topic, msg, _ in sub.iter(30):
            got.append((topic, msg["seq"], msg["data"]))
            if len(got) == len(recorded):
                break
        assert got == recorded
        assert c.call("state")["seq"] == recorded[-1][1]
        sub.close()
        c.close()
    finally:
        t.join(10)
        server.close()


def test_replay_republishes_the_frames(session, tmp_path: Path) -> None:
    _, _, _, out = session
    msgs = _read(out)
    want = [(json.loads(m.data)["seq"], bytes(fmt.pixels_of(n.data)))
            for (t, _, m), (u, _, n) in zip(msgs, msgs[1:]) if t == fmt.FRAME_HEADER_TOPIC and u == fmt.FRAME_TOPIC]
    t, server = _replay_thread(out, f"ipc://{tmp_path}/cmd", 2.0, frames=True)  # frames' PUB drops for a slow reader
    try:
        c = Client(f"ipc://{tmp_path}/cmd", timeout=5)
        frames = c.subscriber(frames=True, hwm=100)
        tel = c.subscriber()  # the replay starts once a telemetry subscriber is there
        got = []
        for _, header, extra in frames.iter(10):
            got.append((header["seq"], extra[0].bytes))
            if len(got) == len(want):
                break
        assert got == want and len(want) >= 4
        frames.close()
        tel.close()
        c.close()
    finally:
        t.join(10)
        server.close()


def test_replay_into_ritactl_watch(session, tmp_path: Path, capsys) -> None:
    _, _, _, out = session
    cmd = f"ipc://{tmp_path}/cmd"
    t, server = _replay_thread(out, cmd, 4.0)  # 2 s recorded, half a second to play
    try:
        assert ctl.main(["--endpoint", cmd, "--json", "watch", "--duration", "2"]) == Exit.OK
        lines = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
        seqs = [m["seq"] for m in lines if m["topic"] == "tracker.point"]  # the snapshot's, then the updates
        tel = [t for t, _, _ in _bus(_read(out)) if not t.startswith("camera.")]  # the replay numbers these
        last = max(n for n, t in enumerate(tel, start=1) if t == "tracker.point")
        assert len(seqs) >= 2 and seqs == sorted(set(seqs)) and seqs[-1] == last  # in order, to the end
    finally:
        t.join(10)
        server.close()


def test_replay_feeds_the_console_bridge(session, tmp_path: Path) -> None:
    _, _, _, out = session
    cmd = f"ipc://{tmp_path}/cmd"
    t, server = _replay_thread(out, cmd, 1.0)
    bridge = Bridge(lambda: Client(cmd, timeout=5))
    try:
        bridge.start()  # hello, the role probe, the snapshot, then the telemetry reader
        assert bridge.role == "viewer" and bridge.hello["replay"] == str(out)
        end = time.monotonic() + 10
        while "tracker.point" not in bridge.latest and time.monotonic() < end:
            time.sleep(0.05)
        assert bridge.latest["tracker.point"]["data"]["n"] >= 1 and bridge.link["bus"] == "up"
    finally:
        bridge.stop()
        t.join(10)
        server.close()


def test_replay_never_takes_a_live_daemons_socket(session) -> None:
    d, _, ep, _ = session
    with pytest.raises(CtlError, match="something is listening there"):
        endpoints(ep)
    assert ctl.main(["replay", "--no-wait", "--endpoint", ep, str(session[3])]) == Exit.USAGE


def test_replay_refuses_commands_it_cannot_answer(tmp_path: Path) -> None:
    server = ReplayServer(f"ipc://{tmp_path}/cmd", "x.mcap")
    t = threading.Thread(target=server.serve, args=(2.0,), daemon=True)
    t.start()
    try:
        with Client(f"ipc://{tmp_path}/cmd", timeout=5) as c:
            assert c.hello()["replay"] == "x.mcap"
            with pytest.raises(CommandError, match="replay of x.mcap") as e:
                c.call("robot.move", distance_mm=10)
            assert e.value.code == "forbidden"
    finally:
        t.join(5)
        server.close()
    assert os.path.exists(tmp_path / "telemetry")


def test_ctrl_c_ends_a_recording_with_a_complete_file(session, tmp_path: Path, capsys) -> None:
    _, _, ep, _ = session
    out = tmp_path / "ctrl-c.mcap"

    def ctrl_c() -> None:  # the operator's Ctrl-C, once the recording runs (its partial file exists)
        deadline = time.monotonic() + 30.0
        while not (tmp_path / ".ctrl-c.mcap.partial").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
        os.kill(os.getpid(), signal.SIGINT)

    timer = threading.Timer(0.0, ctrl_c)
    timer.start()
    try:
        assert ctl.main(["--endpoint", ep, "record", "--out", str(out)]) == Exit.INTERRUPTED
    finally:
        timer.cancel()
    assert "recorded" in capsys.readouterr().out
    assert any(t == "tracker.point" for t, _, _ in _read(out)) and not list(tmp_path.glob(".*"))


def test_replay_skips_channels_of_another_layout(tmp_path: Path) -> None:
    path = tmp_path / "mixed.mcap"
    with open(path, "wb") as f:
        rec = Recorder(f, {}, "none")
        rec.telemetry("robot.state", {"seq": 1, "t_ns": 10, "data": {"x_mm": 1.0}}, 11)
        schema = rec.writer.register_schema("other/Thing", "ros2msg", b"int32 a")
        other = rec.writer.register_channel("/other", "cdr", schema)
        rec.writer.add_message(other, log_time=12, data=b"\x00\x01\x00\x00\x05\x00\x00\x00", publish_time=12)
        rec.telemetry("robot.state", {"seq": 2, "t_ns": 13, "data": {"x_mm": 2.0}}, 14)
        rec.frame({"seq": 1, "pixel_format": "Mono8", "shape": None, "dtype": "|u1"}, b"", 15)  # no shape
        rec.finish()
    assert rec.counts.unsupported == 1
    server = ReplayServer(f"ipc://{tmp_path}/cmd", str(path))
    try:
        with open(path, "rb") as f:
            assert play(server, f, None) == (3, 1)  # two states and the frame's header; /other skipped
        assert server.latest["robot.state"]["data"] == {"x_mm": 2.0}
    finally:
        server.close()


def test_an_error_mid_recording_keeps_a_finished_partial_file(session, tmp_path: Path, capsys, monkeypatch) -> None:
    _, _, ep, _ = session
    out = tmp_path / "disk.mcap"
    write = Recorder.telemetry
    calls = [0]

    def disk_fills(self: Recorder, topic: str, msg: dict[str, Any], recv_ns: int) -> None:
        if calls[0] >= 30:  # 30 bus messages written (with the Foxglove poses some add)
            raise OSError(28, "No space left on device")
        calls[0] += 1
        write(self, topic, msg, recv_ns)

    monkeypatch.setattr(Recorder, "telemetry", disk_fills)
    assert ctl.main(["--endpoint", ep, "record", "--out", str(out), "--duration", "20"]) == Exit.BAD_INPUT
    err = capsys.readouterr().err
    kept = tmp_path / "disk.partial.mcap"
    assert f"kept in {kept}, finished (a valid MCAP file)" in err and "No space left on device" in err
    msgs = _read(kept)  # CRCs, summary and statistics check out
    assert f"after {len(msgs)} messages" in err and not out.exists() and not list(tmp_path.glob(".*"))
    assert len(_bus(msgs)) == 30 and sum(t == "tracker.point" for t, _, _ in msgs) >= 1
    with open(kept, "rb") as f:
        end = {m.name: m.metadata for m in make_reader(f).iter_metadata()}[fmt.END_METADATA_NAME]
    assert end["ended"] == "error" and "No space left" in end["error"] and end["messages"] == str(len(msgs))


def test_a_recording_whose_summary_fails_is_kept_unfinished(session, tmp_path: Path, capsys, monkeypatch) -> None:
    _, _, ep, _ = session
    (tmp_path / "s.partial.mcap").write_bytes(b"an earlier one")  # never overwritten

    def summary_fails(self: Recorder, ended: str = "", error: str = "") -> None:
        self.finishing = True
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(Recorder, "finish", summary_fails)
    assert ctl.main(["--endpoint", ep, "record", "--out", str(tmp_path / "s.mcap"), "--duration", "0.5"]) \
        == Exit.BAD_INPUT
    err = capsys.readouterr().err
    kept = tmp_path / "s.partial-2.mcap"
    assert f"kept in {kept}, NOT finished" in err and "Input/output error" in err
    assert kept.read_bytes().startswith(b"\x89MCAP0\r\n") and kept.stat().st_size > 8  # the data written so far
    assert (tmp_path / "s.partial.mcap").read_bytes() == b"an earlier one"
