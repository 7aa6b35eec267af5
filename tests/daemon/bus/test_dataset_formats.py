"""Datasets with colour and packed pixel formats: stored losslessly, validated, recomputed.

The folders come from the independent writer (tests/dataset_writer.py), which makes its
Bayer mosaics and RGB images itself, from docs/datasets.md ("Images") alone.
"""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from daemon.bus import storage
from daemon.bus.datasets import png_info, validate_folder
from daemon.ctl import main as ctl
from daemon.compute.images import read_image
from tests.daemon.bus.test_datasets import rob_H_cam_error
from tests.dataset_writer import write_referencing


@pytest.mark.parametrize("fmt,stored", [("BayerRG8", (1, 8)), ("BayerRG12p", (1, 16)), ("RGB8", (3, 8))])
def test_colour_datasets_validate_and_recompute(tmp_path, capsys, fmt, stored):
    truth = write_referencing(tmp_path / "ref", pixel_format=fmt)
    assert png_info(tmp_path / "ref" / "run0.png")[2:] == stored
    assert ctl.main(["validate", str(tmp_path / "ref")]) == 0, capsys.readouterr()
    code = ctl.main(["recompute", str(tmp_path / "ref"), "--out", str(tmp_path / "out")])
    assert code == 0, capsys.readouterr()
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    t_err, r_err = rob_H_cam_error(np.array(result["rob_H_cam"]), truth)
    print(f"{fmt}: rob_H_cam error {t_err * 1e3:.2f} µm, {r_err:.5f}°")
    assert t_err < 1e-3 and r_err < 1e-3, (t_err, r_err)  # the bound the Mono8 writer test uses


def test_pixel_format_must_match_the_png(tmp_path):
    write_referencing(tmp_path / "ref", pixel_format="BayerRG8")
    side = json.loads((tmp_path / "ref" / "run0.json").read_text())
    side["camera"]["pixel_format"] = "BayerRG12p"
    (tmp_path / "ref" / "run0.json").write_text(json.dumps(side))
    state = json.loads((tmp_path / "ref" / "state.json").read_text())
    state["obs"]["runs"][0]["header"]["pixel_format"] = "YUV422_8"
    (tmp_path / "ref" / "state.json").write_text(json.dumps(state))
    messages = [str(p) for p in validate_folder(tmp_path / "ref")]
    assert ("dataset.json: $.entries[0].image: image run0.png has 1 channel(s) at 8 bit but pixel format "
            "BayerRG12p is stored with 1 at 16") in messages, messages
    assert any("state.json: $.obs.runs[0].image: image run0.png: "
               "pixel format 'YUV422_8' is not one the computation reads"
               in m for m in messages), messages


def test_colour_frames_are_stored_as_true_rgb_and_read_back(tmp_path):
    ds = storage.Dataset.create(tmp_path, "captures")
    rgb = np.zeros((6, 8, 3), np.uint8)
    rgb[..., 0] = 200  # red
    ds.add_entry("red", {"camera": {"pixel_format": "RGB8", "shape": [6, 8, 3], "dtype": "|u1"}}, image=rgb)
    assert cv2.imread(str(ds.root / "red.png"))[0, 0].tolist() == [0, 0, 200]  # OpenCV reads B, G, R
    img, fmt = read_image(ds.root, "red.png")
    assert fmt == "RGB8" and np.array_equal(img, rgb)
    mosaic = (np.arange(48, dtype=np.uint16).reshape(6, 8) * 85) % 4096
    ds.add_entry("bayer", {"camera": {"pixel_format": "BayerRG12p", "shape": [6, 8], "dtype": "<u2"}},
                 image=mosaic)
    img, fmt = read_image(ds.root, "bayer.png")
    assert fmt == "BayerRG12p" and img.dtype == np.uint16 and np.array_equal(img, mosaic)
    ds.add_entry("old", {"camera": {"shape": [6, 8], "dtype": "|u1"}}, image=mosaic.astype(np.uint8))
    assert read_image(ds.root, "old.png")[1] == "Mono8"  # no pixel format recorded: Mono8
    assert validate_folder(ds.root) == []
