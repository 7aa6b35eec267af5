"""A recorder that cannot hurt the robot (issue 35): it ends on time however fast frames come, drops
and counts the frames it cannot write, and ends cleanly at the free-space floor or --max-size.

Every file is checked with the independent ``mcap`` reader (CRCs, summary, metadata), never with
the project's own replay code. No assertion is on wall-clock speed: a hang is what the timeouts catch.
"""
from __future__ import annotations

import io
import re
import shutil
import time
from pathlib import Path
from typing import Any, Iterator

import pytest
from mcap.reader import make_reader

from daemon.bus.client import Client
from daemon.ctl import main as ctl
from daemon.ctl import mcapfile as fmt
from daemon.ctl import reclimits
from daemon.ctl.exitcodes import CtlError, Exit
from daemon.ctl.reclimits import PROBE_BYTES, RESERVE, Limits, parse_size
from daemon.ctl.record import Recorder
from daemon.ritad.daemon import Daemon
from tests.ritad_up import ritad_in_process
from tools.harness.load import hang_s

#: the simulated camera at its top rate: tiny prerendered frames, asked for far faster than written
FAST_CAMERA = "sim:?size=64x48&noise=0&prerender=4&fps=1000"


def _end_record(path: Path) -> dict[str, str]:
    """The end metadata of a finished file, checked against what the file holds."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        topics = [ch.topic for _, ch, _ in reader.iter_messages(log_time_order=False)]
        assert summary.statistics.message_count == len(topics)
        end = {m.name: m.metadata for m in reader.iter_metadata()}[fmt.END_METADATA_NAME]
    assert end["messages"] == str(len(topics)) and end["frames"] == str(topics.count(fmt.FRAME_CHANNEL))
    return end


def test_sizes_parse_and_errors_name_the_value(tmp_path: Path) -> None:
    assert parse_size("500M", "--max-size") == 500_000_000
    assert parse_size("1.5g", "--min-free") == 1_500_000_000
    assert parse_size("123", "--min-free") == 123 and parse_size("2GB", "--min-free") == 2_000_000_000
    for bad in ("", "lots", "-1G", "5X"):
        with pytest.raises(CtlError) as e:
            parse_size(bad, "--min-free")
        assert e.value.exit == Exit.USAGE and f"--min-free must be a size such as 500M or 2G, got {bad!r}" \
            in e.value.args[0]
    with pytest.raises(CtlError, match="--max-size must be at least 10M, got '1M'"):
        Limits.from_options(tmp_path, None, "1M")


def test_the_floor_is_probed_as_the_file_grows_and_ends_it_before_the_disk_fills() -> None:
    probes: list[int] = []
    free = [10 * PROBE_BYTES]

    def probe(_: Path) -> int:
        probes.append(free[0])
        return free[0]

    limits = Limits(Path("."), min_free=5 * PROBE_BYTES, free=probe)
    assert limits.reason(0, 1000) is None and len(probes) == 1
    assert limits.reason(1000, 1000) is None and len(probes) == 1  # no statvfs per message
    # the file's own growth counts between probes: 5 probes' worth written reaches the floor
    assert limits.reason(4 * PROBE_BYTES, 1000) is None and len(probes) == 2
    free[0] = 5 * PROBE_BYTES  # someone else filled the disk
    assert limits.reason(5 * PROBE_BYTES, 1000) == "min_free" and len(probes) == 3
    assert "--min-free 80.0 MB" in limits.describe("min_free")
    cap = Limits(Path("."), min_free=0, max_size=20_000_000, free=lambda _: 10**12)
    assert cap.reason(20_000_000 - RESERVE - 1000, 1000) is None
    assert cap.reason(20_000_000 - RESERVE - 1000, 1001) == "max_size"


def test_a_limit_stops_the_writing_and_the_file_is_still_finished() -> None:
    buf = io.BytesIO()
    free = [10**12]
    rec = Recorder(buf, {}, "none", Limits(Path("."), min_free=10**9, free=lambda _: free[0]))
    for seq in range(1, 6):
        rec.telemetry("robot.state", {"seq": seq, "t_ns": seq, "data": {"x_mm": 1.0}}, seq)
        if seq == 3:
            free[0] = 10**9  # the disk reaches the floor; the next probe (half a second on) sees it
            rec.limits._probed_t = float("-inf")  # type: ignore[union-attr]  # probe now, not in 0.5 s
    assert rec.ended == "min_free" and rec.counts.messages == 3
    rec.finish(rec.ended)
    path = io.BytesIO(buf.getvalue())
    reader = make_reader(path, validate_crcs=True)
    assert [m.sequence for _, _, m in reader.iter_messages()] == [1, 2, 3]
    assert {m.name: m.metadata for m in reader.iter_metadata()}[fmt.END_METADATA_NAME]["ended"] == "min_free"


@pytest.fixture(scope="module")
def fast(tmp_path_factory) -> Iterator[tuple[Daemon, Client, str]]:
    tmp = tmp_path_factory.mktemp("limits")
    with ritad_in_process(tmp / "rt", tmp / "data", timeout=30, camera=FAST_CAMERA) as (d, c):
        c.call("camera.stream.start")
        try:
            yield d, c, d.server.endpoints[0]
        finally:
            c.call("camera.stream.stop")


@pytest.mark.timeout(120)  # the bug this guards against ran past 60 s for a 3 s recording
def test_duration_ends_a_recording_at_the_cameras_top_rate_and_counts_the_drops(fast, tmp_path: Path, capsys,
                                                                                monkeypatch) -> None:
    _, _, ep = fast
    write = Recorder.frame

    def slow_disk(self: Recorder, header: dict[str, Any], pixels: Any, recv_ns: int) -> None:
        time.sleep(0.02)  # a writer slower than the camera, whatever this machine's speed
        write(self, header, pixels, recv_ns)

    monkeypatch.setattr(Recorder, "frame", slow_disk)
    out = tmp_path / "fast.mcap"
    start = time.monotonic()
    assert ctl.main(["--endpoint", ep, "record", "--out", str(out), "--frames", "every", "1",
                     "--duration", "3"]) == Exit.OK
    assert time.monotonic() - start < hang_s(5)  # ended: 5 s on a quiet machine, more under load
    line = capsys.readouterr().out
    end = _end_record(out)
    assert end["ended"] == "duration" and int(end["frames"]) >= 1
    dropped = int(end["frames_dropped"])
    assert dropped >= 1 and f"{end['frames']} frames ({dropped} dropped)" in line


def test_a_floor_above_the_free_space_ends_the_recording_at_once_cleanly(fast, tmp_path: Path,
                                                                         capsys) -> None:
    _, _, ep = fast
    out = tmp_path / "floor.mcap"
    floor = shutil.disk_usage(tmp_path).free + 10**9  # above what any writer on this machine frees meanwhile
    code = ctl.main(["--endpoint", ep, "record", "--out", str(out), "--frames", "every", "1",
                     "--duration", "60", "--min-free", str(floor)])
    err = capsys.readouterr().err
    assert code == Exit.BAD_INPUT and "the recording ended early: free space on" in err
    assert re.search(rf"--min-free {floor / 1e6:.1f} MB", err), err
    end = _end_record(out)  # under its real name, finished: a valid MCAP file
    assert end["ended"] == "min_free" and end["messages"] == "0" and not list(tmp_path.glob(".*"))


def test_max_size_ends_the_recording_before_the_file_passes_it(fast, tmp_path: Path, capsys,
                                                              monkeypatch) -> None:
    _, _, ep = fast
    monkeypatch.setattr(reclimits, "MIN_MAX_SIZE", 0)  # 5 MB: 1 MB past the reserve, hundreds of tiny frames
    out = tmp_path / "cap.mcap"
    assert ctl.main(["--endpoint", ep, "record", "--out", str(out), "--frames", "every", "1",
                     "--duration", "60", "--max-size", "5M", "--compression", "none"]) == Exit.OK
    assert "--max-size 5.0 MB" in capsys.readouterr().err
    assert _end_record(out)["ended"] == "max_size" and out.stat().st_size <= 5_000_000


def test_the_recording_thread_gives_way_and_no_other_thread_does() -> None:
    import os
    import threading

    from daemon.ctl.record import RECORD_NICE, _at_low_priority

    def nice_here() -> float:
        return float(os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))

    before = nice_here()
    assert _at_low_priority(nice_here) >= min(RECORD_NICE, 19)  # the recording's own thread
    assert nice_here() == before  # the caller's (in ritad's tests: the daemon's) is untouched


def test_frames_as_png_from_the_cli_and_a_clear_error_without_opencv(fast, tmp_path: Path, monkeypatch,
                                                                      capsys) -> None:
    import sys

    _, _, ep = fast
    out = tmp_path / "png.mcap"
    assert ctl.main(["--endpoint", ep, "record", "--out", str(out), "--frames", "every", "1",
                     "--frames-format", "png", "--duration", "1"]) == Exit.OK
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    images = {summary.schemas[c.schema_id].name for c in summary.channels.values()
              if c.topic == fmt.FRAME_CHANNEL}
    assert images == {fmt.COMPRESSED_IMAGE_SCHEMA} and int(_end_record(out)["frames"]) >= 1
    monkeypatch.setitem(sys.modules, "cv2", None)  # an install without OpenCV
    capsys.readouterr()
    assert ctl.main(["--endpoint", ep, "record", "--out", str(tmp_path / "no.mcap"), "--frames", "every", "1",
                     "--frames-format", "jpeg", "--duration", "1"]) == Exit.BAD_INPUT
    assert "--frames-format jpeg needs OpenCV" in capsys.readouterr().err and not list(tmp_path.glob("*no*"))
