"""Atomic files and dataset folders: a failed write leaves the old file intact."""
import json

import numpy as np
import pytest

from daemon.bus import storage


def test_atomic_write_replaces_and_leaves_no_temp(tmp_path):
    p = tmp_path / "a" / "x.json"
    storage.atomic_write_json(p, {"v": 1})
    storage.atomic_write_json(p, {"v": 2})
    assert json.loads(p.read_text()) == {"v": 2}
    assert [f.name for f in p.parent.iterdir()] == ["x.json"]


def test_failed_write_keeps_old_content(tmp_path):
    p = tmp_path / "x.json"
    storage.atomic_write_json(p, {"v": 1})
    with pytest.raises(TypeError):
        storage.atomic_write_json(p, {"v": object()})
    assert json.loads(p.read_text()) == {"v": 1}
    assert [f.name for f in tmp_path.iterdir()] == ["x.json"]


def test_dataset_entries_are_readable_without_this_project(tmp_path):
    import cv2

    ds = storage.Dataset.create(tmp_path, "unit test", meta={"who": "test"})
    img = (np.arange(64 * 48) % 251).astype(np.uint8).reshape(48, 64)
    path = ds.add_entry("one", {"k": 1}, image=img)
    again = storage.Dataset(ds.root)
    assert again.manifest["entries"][0]["image"] == "one.png"
    assert json.loads(path.read_text()) == {"k": 1, "image_file": "one.png"}
    assert np.array_equal(cv2.imread(str(ds.root / "one.png"), cv2.IMREAD_UNCHANGED), img)
    img16 = (np.arange(64 * 48, dtype=np.uint16) * 13).reshape(48, 64)
    ds.add_entry("two", {}, image=img16)
    assert np.array_equal(cv2.imread(str(ds.root / "two.png"), cv2.IMREAD_UNCHANGED), img16)
