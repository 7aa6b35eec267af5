"""A live recording read by strict, independent tools: every message valid against its channel's schema.

ritad --sim runs in-process; ``ritactl record`` records it (tracker at 1 kHz, frames) while
commands come and go, accepted and refused, so ``daemon.command`` carries both its null and its
filled ``key``/``code``/``message``. The file is read with the ``mcap`` library's reader
(``make_reader``, CRCs on) and every JSON message is checked with ``jsonschema`` against its
channel's schema; each channel's sequences run 1, 2, 3 … with no gap. The project's own reader
(``ritactl replay``) is not used: it is the thing an independent consumer must not need.
"""
from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from mcap.reader import make_reader

from daemon.bus.names import Topic
from daemon.bus.protocol import CommandError
from daemon.ctl import main as ctl
from daemon.ctl import mcapfile as fmt
from daemon.ctl.exitcodes import Exit
from fakes.operator import lock_on_robot
from tests.ritad_up import SMALL_CAMERA, ritad_in_process
from tools.harness.load import hang_s

pytestmark = pytest.mark.timeout(120)


def _record_with_commands(tmp_path: Path, out: Path) -> None:
    cam = SMALL_CAMERA + "&fps=20"
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", timeout=30, camera=cam) as (d, c):
        lock_on_robot(c)
        result: list[int] = []
        rec = threading.Thread(target=lambda: result.append(ctl.main(
            ["--endpoint", d.server.endpoints[0], "record", "--out", str(out), "--duration", "3",
             "--frames", "every", "1"])), daemon=True)
        rec.start()
        end = time.monotonic() + hang_s(20)
        while not (out.parent / f".{out.name}.partial").exists() and time.monotonic() < end:
            time.sleep(0.02)
        time.sleep(0.3)  # subscribed
        c.call("tracker.stream.start", rate_hz=1000.0)  # accepted: key, code and message null
        c.call("camera.stream.start")
        with pytest.raises(CommandError):
            c.call("robot.move", distance_mm="far")  # refused: code and message filled
        rec.join(hang_s(30))
        c.call("tracker.stream.stop")
        c.call("camera.stream.stop")
    assert result == [Exit.OK]


def test_every_message_is_valid_for_its_schema_and_channel_sequences_have_no_gaps(tmp_path: Path) -> None:
    out = tmp_path / "strict.mcap"
    _record_with_commands(tmp_path, out)
    seqs: dict[str, list[int]] = {}
    checked: dict[str, int] = {}
    validators: dict[int, Any] = {}
    commands = []
    with open(out, "rb") as f:
        for sch, ch, m in make_reader(f, validate_crcs=True).iter_messages(log_time_order=False):
            seqs.setdefault(ch.topic, []).append(m.sequence)
            if ch.message_encoding != "json":
                assert ch.topic == fmt.FRAME_TOPIC and sch is not None and sch.encoding == "ros2msg"
                continue
            assert sch is not None and sch.encoding == "jsonschema"
            if sch.id not in validators:
                schema = json.loads(sch.data)
                jsonschema.validators.validator_for(schema).check_schema(schema)
                validators[sch.id] = jsonschema.validators.validator_for(schema)(schema)
            data = json.loads(m.data)
            errors = [f"{e.json_path}: {e.message}" for e in validators[sch.id].iter_errors(data)]
            assert not errors, (ch.topic, m.sequence, errors[:3])
            checked[ch.topic] = checked.get(ch.topic, 0) + 1
            if ch.topic == Topic.DAEMON_COMMAND:
                commands.append(data)
    for topic, got in seqs.items():
        assert got == list(range(1, len(got) + 1)), (topic, got[:10])
    assert checked.get(str(Topic.TRACKER_POINT), 0) >= 10 and checked.get(fmt.FRAME_HEADER_TOPIC, 0) >= 5
    refused = [r for r in commands if r["cmd"] == "robot.move"]
    assert refused and refused[0]["ok"] is False and isinstance(refused[0]["code"], str)
    accepted = [r for r in commands if r["cmd"] == "tracker.stream.start"]
    assert accepted and accepted[0]["ok"] is True and "code" not in accepted[0]  # its null left out
