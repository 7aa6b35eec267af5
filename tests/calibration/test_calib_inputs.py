"""Plate and camera-model files: a bad or missing key is named with its file."""
from __future__ import annotations

import copy
import json
import math
import re

import numpy as np
import pytest

from calibration.camera_model import CameraModel
from calibration.io import load_plate
from calibration.plate import Plate
from fakes.world import World

SRC = "ds/referencing/state.json: plate"


@pytest.fixture(scope="module")
def plate_dict() -> dict:
    return World().plate().to_dict()


@pytest.fixture(scope="module")
def model_dict() -> dict:
    return CameraModel(np.array([[470.0, 0, 500], [0, 470.0, 370], [0, 0, 1]]), np.zeros(5), (1000, 750)).to_dict()


@pytest.mark.parametrize("key", ["plate_id", "board_cols", "board_rows", "square_mm", "marker_mm", "aruco_dict",
                                 "nests_ref_nst", "smr_offset_mm"])
def test_missing_plate_key_is_named_with_the_file(plate_dict: dict, key: str) -> None:
    d = {k: v for k, v in plate_dict.items() if k != key}
    with pytest.raises(ValueError) as exc:
        Plate.from_dict(d, source=SRC)
    assert str(exc.value) == f"{SRC}: missing key(s) {key!r}"


@pytest.mark.parametrize("key, value, says", [
    ("board_cols", "40", "board_cols must be a whole number"),
    ("board_rows", True, "board_rows must be a whole number"),
    ("square_mm", float("nan"), "square_mm must be a finite number"),
    ("marker_mm", None, "marker_mm must be a finite number"),
    ("aruco_dict", 5, "aruco_dict must be a JSON string"),
    ("nests_ref_nst", [1, 2, 3], "nests_ref_nst must be a JSON object"),
    ("smr_offset_mm", "19.05", "smr_offset_mm must be a finite number"),
    ("colour", "red", "unknown key(s) 'colour'"),
    ("schema", 2, "plate schema 2 is not supported"),
])
def test_wrong_plate_value_is_named(plate_dict: dict, key: str, value, says: str) -> None:
    d = copy.deepcopy(plate_dict)
    d[key] = value
    with pytest.raises(ValueError, match=f"^{re.escape(SRC)}: .*{re.escape(says)}"):
        Plate.from_dict(d, source=SRC)


def test_bad_nest_point_is_named(plate_dict: dict) -> None:
    d = copy.deepcopy(plate_dict)
    d["nests_ref_nst"]["green"] = [1.0, "x", 3.0]
    with pytest.raises(ValueError, match=rf"^{SRC}: nests_ref_nst.green must be 3 finite numbers"):
        Plate.from_dict(d, source=SRC)
    del d["nests_ref_nst"]["green"]
    with pytest.raises(ValueError, match=rf"^{SRC}: plate .*nests must be exactly"):
        Plate.from_dict(d, source=SRC)
    assert set(plate_dict["nests_ref_nst"]) == {"red", "green", "blue"}  # the caller's dict is untouched


def test_plate_file_round_trip_and_bad_json(plate_dict: dict, tmp_path) -> None:
    p = tmp_path / "plate.json"
    p.write_text(json.dumps(Plate.from_dict(plate_dict).to_dict()))
    assert load_plate(p).to_dict() == plate_dict
    p.write_text('{"schema": 1, "plate_id": ')
    with pytest.raises(ValueError, match=rf"^{p}: not a JSON plate definition"):
        load_plate(p)
    p.write_text("[]")
    with pytest.raises(ValueError, match=rf"^{p}: expected a JSON object"):
        load_plate(p)


@pytest.mark.parametrize("key", ["K", "dist", "size"])
def test_missing_camera_model_key_is_named(model_dict: dict, key: str) -> None:
    d = {k: v for k, v in model_dict.items() if k != key}
    with pytest.raises(ValueError) as exc:
        CameraModel.from_dict(d, source="cam.json")
    assert str(exc.value) == f"cam.json: missing key(s) {key!r}"


@pytest.mark.parametrize("key, value", [("K", [[1, 0], [0, 1]]), ("K", "eye"), ("dist", [0, 0, 0]),
                                        ("dist", [0, 0, None, 0, 0]), ("size", [1000.5, 750]), ("size", 1000)])
def test_wrong_camera_model_value_is_named(model_dict: dict, key: str, value) -> None:
    d = dict(model_dict, **{key: value})
    with pytest.raises(ValueError, match=rf"^cam.json: {key} must be"):
        CameraModel.from_dict(d, source="cam.json")


def _mutate(d: dict, rng: np.random.Generator) -> dict:
    """One random change somewhere in a JSON tree: drop a key, or replace a value."""
    d = copy.deepcopy(d)
    node, key = d, None
    while True:
        keys = list(node) if isinstance(node, dict) else list(range(len(node)))
        key = keys[rng.integers(len(keys))]
        if isinstance(node[key], (dict, list)) and node[key] and rng.random() < 0.6:
            node = node[key]
            continue
        break
    if isinstance(node, dict) and rng.random() < 0.3:
        del node[key]
    else:
        node[key] = [None, "x", -1, 0, 1e308, math.nan, math.inf, True, [], {}, [1, 2], 3.5][rng.integers(12)]
    return d


def test_random_mutations_give_a_named_value_error_or_a_valid_object(plate_dict: dict, model_dict: dict) -> None:
    rng = np.random.default_rng(12)
    errors = 0
    for i in range(600):
        for cls, good in ((Plate, plate_dict), (CameraModel, model_dict)):
            bad = _mutate(good, rng)
            try:
                cls.from_dict(json.loads(json.dumps(bad)), source=f"m{i}.json")
            except ValueError as exc:
                errors += 1
                assert str(exc).startswith(f"m{i}.json: "), exc
    assert errors > 600  # most mutations are errors; none escaped as another exception
