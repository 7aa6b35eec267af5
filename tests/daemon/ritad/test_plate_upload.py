"""calib.plate.upload and ``ritactl plate upload``: a laptop's plate into the robot's calibration folder.

Checked against the plate schema before anything is written, the name confined to the
calibration folder, a replaced plate kept in calibration/history/plates/, an operator's
command (a viewer is refused), and the stored file the one referencing then reads.
"""
from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Iterator

import pytest

from calibration.plate import Plate
from daemon.bus.client import Client
from daemon.bus.command_table import COMMANDS
from daemon.bus.protocol import CommandError
from daemon.ctl import main as ctl
from daemon.ritad import config
from daemon.ritad.daemon import Daemon


@pytest.fixture(scope="module")
def served(tmp_path_factory) -> Iterator[tuple[Daemon, Path, dict]]:
    tmp = tmp_path_factory.mktemp("plates")
    cfg = config.sim_config(tmp / "rt", tmp / "data")
    cfg.daemon.start_worker = False
    cfg.devices.camera = "sim:?size=64x48&noise=0"
    d = Daemon(cfg)
    d.start()
    try:
        data = Path(cfg.daemon.data_dir)
        plate = json.loads((data / "sim" / "plate.json").read_text())  # the installer's design file
        yield d, data, plate
    finally:
        d.stop()


def client(d: Daemon) -> Client:
    return Client(d.server.endpoints[0], timeout=10)


def test_a_plate_is_stored_checked_and_a_replaced_one_is_kept(served) -> None:
    d, data, plate = served
    with client(d) as c:
        first = c.call("calib.plate.upload", plate=plate, name="surveyed.json")
        assert first["path"] == "calibration/surveyed.json" and first["replaced"] is None and not first["unchanged"]
        assert json.loads((data / first["path"]).read_text()) == plate
        Plate.from_dict(json.loads((data / first["path"]).read_text()))  # what referencing reads
        again = c.call("calib.plate.upload", plate=plate, name="surveyed.json")
        assert again["unchanged"] and again["replaced"] is None and again["sha256"] == first["sha256"]
        moved = copy.deepcopy(plate)
        moved["nests_ref_nst"]["red"][0] += 0.05  # a new survey of the same plate
        second = c.call("calib.plate.upload", plate=moved, name="surveyed.json")
    assert second["replaced"].startswith("calibration/history/plates/surveyed-")
    assert json.loads((data / second["replaced"]).read_text()) == plate  # nothing lost
    assert json.loads((data / "calibration" / "surveyed.json").read_text()) == moved


@pytest.mark.parametrize("change,field", [
    (lambda p: p.pop("nests_ref_nst"), "nests_ref_nst"),
    (lambda p: p.update(square_mm=-3), "square_mm"),
    (lambda p: p["nests_ref_nst"].update(red=[1, 2]), "red"),
    (lambda p: p.update(marker_mm=p["square_mm"] * 2), "marker_mm"),
    (lambda p: p.update(aruco_dict="4X4"), "aruco_dict"),
])
def test_a_bad_plate_is_refused_naming_the_field_and_nothing_is_written(served, change, field) -> None:
    d, data, plate = served
    bad = copy.deepcopy(plate)
    change(bad)
    with client(d) as c, pytest.raises(CommandError) as exc:
        c.call("calib.plate.upload", plate=bad, name="bad.json")
    assert exc.value.code == "bad_args" and field in str(exc.value), str(exc.value)
    assert not (data / "calibration" / "bad.json").exists()


@pytest.mark.parametrize("name", ["../escape.json", "sub/plate.json", ".hidden.json", "plate.txt", "active.json",
                                  "camera_model.json", "a" * 200 + ".json", ""])
def test_a_name_outside_the_calibration_folder_or_the_workers_own_is_refused(served, name) -> None:
    d, data, plate = served
    with client(d) as c, pytest.raises(CommandError) as exc:
        c.call("calib.plate.upload", plate=plate, name=name)
    assert exc.value.code == "bad_args" and "name=" in str(exc.value)
    assert not (data / "escape.json").exists() and not (data / "calibration" / "sub").exists()


def test_it_is_an_operators_command() -> None:
    assert COMMANDS["calib.plate.upload"].role == "operator"


def test_ritactl_plate_upload_stores_and_says_where(served, tmp_path, capsys) -> None:
    d, data, plate = served
    f = tmp_path / "plate-2026.json"
    f.write_text(json.dumps(plate))
    code = ctl.main(["--endpoint", d.server.endpoints[0], "plate", "upload", str(f)])
    out = capsys.readouterr().out
    assert code == 0 and "calibration/plate-2026.json" in out and "plate calibration/plate-2026.json" in out
    assert json.loads((data / "calibration" / "plate-2026.json").read_text()) == plate
    (tmp_path / "broken.json").write_text("{not json")
    assert ctl.main(["--endpoint", d.server.endpoints[0], "plate", "upload", str(tmp_path / "broken.json")]) == 5
    bad = dict(plate, board_cols=1)
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    assert ctl.main(["--endpoint", d.server.endpoints[0], "plate", "upload", str(tmp_path / "bad.json")]) == 4
    assert "board_cols" in capsys.readouterr().err
