"""ritactl recompute decodes the first image during validation: same pixels, and a bad folder still fails first."""
from __future__ import annotations

import json
import shutil
import struct
import threading
import zlib

import numpy as np
import pytest

from daemon.bus.datasets import DatasetInvalid
from daemon.compute.images import PrefetchedLoader, first_image, grey_loader
from daemon.compute.procedures import COMPUTE
from daemon.compute.recompute import recompute
from tests.dataset_writer import write_referencing


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("prefetch") / "ref"
    write_referencing(root)
    return root


def test_prefetched_result_is_the_plain_loaders(folder):
    state = json.loads((folder / "state.json").read_text())
    plain = COMPUTE[state["procedure"]](state["obs"], grey_loader(folder))
    result, _ = recompute(folder)
    assert first_image(folder) == state["obs"]["runs"][0]["image"]
    for key in ("rob_H_cam", "rob_H_scn", "runs", "verdict", "uncertainty"):
        assert result[key] == plain[key], key
    with PrefetchedLoader(folder, first_image(folder)) as load:
        name = first_image(folder)
        assert np.array_equal(load(name), grey_loader(folder)(name))
        assert np.array_equal(load(name), grey_loader(folder)(name))  # a second request reads the file again


def _crc_chunk(tag: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + tag + body + struct.pack(">I", zlib.crc32(tag + body) & 0xFFFFFFFF)


@pytest.mark.parametrize("damage", ["truncated", "huge header"])
def test_a_bad_image_is_a_dataset_problem_and_no_thread_is_left(folder, tmp_path, damage):
    root = tmp_path / "ref"
    shutil.copytree(folder, root)
    png = root / first_image(root)
    data = png.read_bytes()
    if damage == "truncated":
        png.write_bytes(data[: len(data) // 2])
    else:  # an IHDR stating 100000 x 100000 px: never decoded, the check refuses it
        ihdr = struct.pack(">IIBBBBB", 100000, 100000, 8, 0, 0, 0, 0)
        png.write_bytes(data[:8] + _crc_chunk(b"IHDR", ihdr) + data[33:])
        assert PrefetchedLoader(root, png.name)._thread is None
    before = threading.active_count()
    with pytest.raises(DatasetInvalid, match=png.name):
        recompute(root)
    assert threading.active_count() == before


def test_a_decode_error_reaches_the_caller(tmp_path):
    (tmp_path / "a.png").write_bytes(b"\x89PNG\r\n\x1a\n" + _crc_chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 4, 8, 0, 0, 0, 0)))
    with PrefetchedLoader(tmp_path, "a.png") as load:
        with pytest.raises(FileNotFoundError, match="unreadable image"):
            load("a.png")
