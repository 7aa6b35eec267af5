"""Atomic files and dataset folders: a failed write leaves the old file intact."""
import json
import os

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


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="names an fd through /proc")
def test_atomic_write_fsyncs_the_file_and_its_folder(tmp_path, monkeypatch):
    """The data and the rename are both durable: the file's fd, then the folder's, are fsynced."""
    synced: list[str] = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync",
                        lambda fd: (synced.append(os.readlink(f"/proc/self/fd/{fd}")), real_fsync(fd)))
    p = tmp_path / "x.bin"
    storage.atomic_write_bytes(p, b"new")
    assert p.read_bytes() == b"new"
    assert len(synced) == 2 and synced[0].startswith(str(tmp_path / ".x.bin.")) and synced[1] == str(tmp_path)


def test_write_failing_midway_keeps_old_file_and_no_temp(tmp_path, monkeypatch):
    """A disk error after the bytes are written but before the rename leaves the old file whole."""
    p = tmp_path / "x.txt"
    storage.atomic_write_text(p, "old")

    def broken(fd):
        raise OSError(5, "Input/output error")
    monkeypatch.setattr(os, "fsync", broken)
    with pytest.raises(OSError, match="Input/output"):
        storage.atomic_write_text(p, "new " * 10000)
    assert p.read_text() == "old"
    assert [f.name for f in tmp_path.iterdir()] == ["x.txt"]


def test_folder_that_cannot_be_opened_is_not_an_error(tmp_path, monkeypatch):
    """Windows cannot open a directory to fsync it: the write still succeeds."""
    real_open = os.open

    def no_dirs(path, flags, *a):
        if os.path.isdir(path):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, flags, *a)
    monkeypatch.setattr(os, "open", no_dirs)
    storage.atomic_write_bytes(tmp_path / "x.bin", b"ok")
    assert (tmp_path / "x.bin").read_bytes() == b"ok"


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
