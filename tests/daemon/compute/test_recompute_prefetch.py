"""ritactl recompute checks and decodes its first image once: the same pixels, and a bad folder still fails first."""
from __future__ import annotations

import json
import shutil
import struct
import threading
import zlib

import cv2
import numpy as np
import pytest

import daemon.bus.png_check as png_check
import daemon.compute.images as images
from daemon.bus.datasets import DatasetInvalid
from daemon.bus.png_check import read_png
from daemon.compute.images import PrefetchedLoader, first_image, grey_loader, read_image
from daemon.compute.png_decode import decode_png
from daemon.compute.procedures import COMPUTE
from daemon.compute.recompute import recompute
from tests.dataset_writer import write_referencing


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("prefetch") / "ref"
    write_referencing(root)
    return root


def test_the_result_is_the_plain_loaders_and_the_image_is_read_once(folder, monkeypatch):
    state = json.loads((folder / "state.json").read_text())
    plain = COMPUTE[state["procedure"]](state["obs"], grey_loader(folder))
    reads = []

    def counted(path):
        reads.append(path)
        return read_png(path)
    monkeypatch.setattr(png_check, "read_png", counted)
    monkeypatch.setattr(images, "read_png", counted)
    result, _ = recompute(folder)
    assert [p.name for p in reads] == [state["obs"]["runs"][0]["image"]] == [first_image(folder)]
    for key in ("rob_H_cam", "rob_H_scn", "runs", "verdict", "uncertainty"):
        assert result[key] == plain[key], key
    with PrefetchedLoader(folder, first_image(folder)) as load:
        name = first_image(folder)
        assert np.array_equal(load(name), grey_loader(folder)(name))
        assert np.array_equal(load(name), grey_loader(folder)(name))  # a second request reads the file again


def _chunk(tag: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + tag + body + struct.pack(">I", zlib.crc32(tag + body) & 0xFFFFFFFF)


def _png(rows: bytes, w: int, h: int, depth: int, colour: int, extra: bytes = b"") -> bytes:
    """A PNG from filtered scanlines, written here (not by OpenCV)."""
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, 0)) + extra
            + _chunk(b"IDAT", zlib.compress(rows)) + _chunk(b"IEND", b""))


@pytest.mark.parametrize("damage", ["truncated", "huge header"])
def test_a_bad_image_is_a_dataset_problem_and_no_thread_is_left(folder, tmp_path, damage):
    root = tmp_path / "ref"
    shutil.copytree(folder, root)
    png = root / first_image(root)
    data = png.read_bytes()
    if damage == "truncated":
        png.write_bytes(data[: len(data) // 2])
    else:  # an IHDR stating 100000 x 100000 px: refused before anything inflates or decodes it
        png.write_bytes(data[:8] + _chunk(b"IHDR", struct.pack(">IIBBBBB", 100000, 100000, 8, 0, 0, 0, 0))
                        + data[33:])
        with PrefetchedLoader(root, png.name) as load:
            with pytest.raises(ValueError, match="implausible size"):
                load.png_info(png)
            load._thread.join()
            assert load._out is None
    before = threading.active_count()
    with pytest.raises(DatasetInvalid, match=png.name):
        recompute(root)
    assert threading.active_count() == before


@pytest.mark.parametrize("kind", ["mono8", "mono16", "rgb8", "rgba8", "rgb16"])
def test_decoded_rows_are_opencvs_pixels(tmp_path, kind):
    """cv2.imwrite's PNGs (every row Sub) decoded from the check's rows equal OpenCV's decode, in RGB order."""
    rng = np.random.default_rng(3)
    depth = np.uint16 if kind.endswith("16") else np.uint8
    shape = {"mono": (37, 53), "rgb": (37, 53, 3), "rgba": (37, 53, 4)}[kind.rstrip("0123456789")]
    img = rng.integers(0, np.iinfo(depth).max + 1, shape, dtype=depth)
    path = tmp_path / "x.png"
    cv2.imwrite(str(path), img)  # written as B, G, R(, A)
    got = decode_png(read_png(path))
    assert got is not None and got.dtype == img.dtype
    assert np.array_equal(got, read_image(tmp_path, "x.png")[0])


def test_other_filters_and_chunks_are_left_to_opencv(tmp_path):
    rng = np.random.default_rng(4)
    px = rng.integers(0, 256, (6, 9), dtype=np.uint8)
    sub = np.diff(px.astype(np.int16), axis=1, prepend=0).astype(np.uint8)
    mixed = b"".join(bytes([k]) + (sub[y] if k == 1 else px[y]).tobytes() for y, k in enumerate([0, 1, 1, 0, 1, 0]))
    (tmp_path / "m.png").write_bytes(_png(mixed, 9, 6, 8, 0))
    assert np.array_equal(decode_png(read_png(tmp_path / "m.png")), px)
    assert np.array_equal(px, cv2.imread(str(tmp_path / "m.png"), cv2.IMREAD_UNCHANGED))
    up = b"".join(bytes([2 if y else 0]) + px[y].tobytes() for y in range(6))  # an Up row: OpenCV decodes
    (tmp_path / "u.png").write_bytes(_png(up, 9, 6, 8, 0))
    assert decode_png(read_png(tmp_path / "u.png")) is None
    plain = b"".join(b"\x00" + px[y].tobytes() for y in range(6))
    (tmp_path / "t.png").write_bytes(_png(plain, 9, 6, 8, 0, _chunk(b"tRNS", b"\x00\x07")))  # transparency
    assert decode_png(read_png(tmp_path / "t.png")) is None


def test_a_decode_error_reaches_the_caller(tmp_path):
    """A file the check passes but this path cannot decode goes to OpenCV, whose error reaches the caller."""
    (tmp_path / "a.png").write_bytes(_png(b"\x00" * 5, 4, 1, 8, 3))  # a palette image without its palette
    with PrefetchedLoader(tmp_path, "a.png") as load:
        assert load.png_info(tmp_path / "a.png") == (4, 1, 1, 8)
        with pytest.raises(FileNotFoundError, match="unreadable image"):
            load("a.png")
