"""Plugins: the simulator enters ritad as a third-party package would (daemon/ritad/plugins.py)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from daemon.bus import station
from daemon.bus.command_table import COMMANDS, TABLE, Arg, Command, CommandTable
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.ritad import plugins
from tests.ritad_up import ritad_in_process

ROOT = Path(__file__).resolve().parents[3]


def test_the_simulator_is_an_installed_plugin_with_its_commands_in_the_daemons_table():
    table = CommandTable()
    found = plugins.installed(table)
    assert "sim" in found
    assert {c.name for c in found["sim"].commands} <= set(table)
    assert table["sim.place_robot_on_plate"].motion == "moves"  # latched by a STOP like robot.move
    assert all(table[c.name].plugin == "sim" for c in found["sim"].commands)
    assert set(COMMANDS) == {c.name for c in TABLE}  # the product's table is left as it was
    assert "sim.truth" not in COMMANDS and table.moves("sim.place_robot_on_plate")


def test_a_plugin_can_neither_replace_a_product_command_nor_name_one_outside_its_own():
    table = CommandTable()
    with pytest.raises(ValueError, match="'robot.move' is already declared by the product"):
        table.register("robot", (Command("robot.move", "mine"),))
    with pytest.raises(ValueError, match="must be named x.<verb>"):
        table.register("x", (Command("sim.truth", "mine"),))
    table.register("sim", plugins.installed()["sim"].commands)
    before = dict(table)
    table.register("sim", plugins.installed()["sim"].commands)  # the same plugin again: nothing changes
    assert dict(table) == before


def test_a_daemon_without_a_sim_device_answers_the_simulators_commands_not_found(tmp_path):
    from daemon.ritad.services import Services

    unused = None
    running = plugins.Running()  # the plugin is installed but no session started
    handlers = running.handlers(unused, plugins.installed())
    assert set(handlers) == {c.name for c in plugins.installed()["sim"].commands}
    with pytest.raises(CommandError) as e:
        handlers["sim.truth"](type("Req", (), {"cmd": "sim.truth", "args": {}})())
    assert e.value.code == ErrorCode.NOT_FOUND and "plugin 'sim' is not running" in str(e.value)
    assert Services  # the handlers need no services without a session


def test_ritad_reads_the_station_the_simulators_installer_wrote_without_touching_its_config(tmp_path):
    with ritad_in_process(tmp_path / "rt", tmp_path / "data") as (d, c):
        assert d.config.tracker.abs_H_trk is None  # ritad's config is what was loaded
        written = json.loads((tmp_path / "data" / station.STATION_FILE).read_text())["abs_H_trk"]
        assert d.abs_H_trk == written == c.call("sim.truth")["abs_H_trk"]
        assert c.call("hello")["sim"] is True
        assert c.call("help")["commands"]["sim.hold_board"]["role"] == "operator"


@pytest.mark.parametrize("matrix, words", [
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]], "det R = -1"),
    ([[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "not a rigid transform"),
    ([[1, 0, 0]], "4x4 matrix"),
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, float("nan")], [0, 0, 0, 1]], "finite"),
])
def test_a_bad_station_file_is_named(tmp_path, matrix, words):
    f = tmp_path / station.STATION_FILE
    f.parent.mkdir(parents=True)
    f.write_text(json.dumps({"abs_H_trk": matrix}))
    with pytest.raises(station.StationError) as e:
        station.abs_H_trk(None, tmp_path)
    assert str(f) in str(e.value) and words in str(e.value)
    assert station.abs_H_trk(station.IDENTITY, tmp_path)[1] == "config [tracker] abs_H_trk"  # config wins
    assert station.abs_H_trk(None, tmp_path / "none")[0] == station.IDENTITY


def test_check_config_names_a_bad_station_file_with_exit_2(tmp_path):
    data = tmp_path / "data"
    (data / "calibration").mkdir(parents=True)
    (data / station.STATION_FILE).write_text("{not json")
    cfg = tmp_path / "c.toml"
    cfg.write_text(f"[daemon]\ncommand_endpoints = ['ipc://{tmp_path}/c']\ntelemetry_endpoints = ['ipc://{tmp_path}/t']\n"
                   f"frame_endpoints = ['ipc://{tmp_path}/f']\ndata_dir = '{data}'\n"
                   "[devices]\ncamera = 'sim:'\ntracker = 'sim:'\nrobot = 'sim:'\n")
    r = subprocess.run([sys.executable, "-m", "daemon.ritad.main", "--check-config", str(cfg)], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "tracker_station.json: not valid JSON" in r.stderr and "Traceback" not in r.stderr


def test_a_plugin_command_declared_with_an_arg_is_validated_like_the_products():
    table = CommandTable()
    plugins.installed(table)
    args = table.validate("sim.survey_images", {"views": 5})
    assert args == {"views": 5, "width_px": 2400}
    with pytest.raises(CommandError) as e:
        table.validate("sim.survey_images", {"views": 99})
    assert e.value.code == ErrorCode.BAD_ARGS and "'views'" in str(e.value)
    assert isinstance(plugins.installed()["sim"].commands[1].args[0], Arg)


def test_the_station_files_own_source_is_reported_with_it(tmp_path):
    """A station file left by the simulator in a data dir later used with a real tracker says so in the log."""
    f = tmp_path / station.STATION_FILE
    f.parent.mkdir(parents=True)
    f.write_text(json.dumps({"abs_H_trk": station.IDENTITY, "source": "simulated world (seed 1, profile ideal)"}))
    assert station.abs_H_trk(None, tmp_path)[1] == f"{f} (simulated world (seed 1, profile ideal))"
