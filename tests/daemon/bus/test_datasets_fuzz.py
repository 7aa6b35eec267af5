"""``ritactl validate`` on 1,000 seeded random mutations of a good dataset folder.

Missing keys, wrong types, NaN/inf, wrong shapes, renamed keys, broken JSON text,
truncated/corrupted/missing/resized images: validation never raises and names a
problem for each mutation, or, when a mutation leaves the folder valid (e.g. a
changed note), ``ritactl recompute`` ends with a documented exit code (run once per
distinct input it reads: state.json + image; manifest-only changes do not change it).
"""
import copy
import json
import math
import random
import shutil
import struct
import zlib

import cv2
import numpy as np
import pytest

from daemon.ctl import main as ctl
from daemon.bus.datasets import Problem, validate_folder
from tests.dataset_writer import write_referencing
from tests.fuzzscale import cases

N_MUTATIONS = cases(1000, 300)
WRONG_VALUES = [None, "x", "", 0, -1, 1.5, True, [], {}, [1, 2], [[1, 2, 3]], float("nan"), float("inf"),
                -1e308, "../../etc/passwd", "run0.tif", {"a": 1}, 2 ** 70]


def paths(doc, prefix=()):
    """Every (path, value) inside a JSON document."""
    yield prefix, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from paths(v, (*prefix, i))


def mutate_json(doc, rng: random.Random):
    """(new document or raw text, description) for one random structural change."""
    doc = copy.deepcopy(doc)
    spots = [p for p, _ in paths(doc) if p]
    path = rng.choice(spots)
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    last = path[-1]
    op = rng.choice(["delete", "wrong", "wrong", "rename", "shape", "nan"])
    if op == "delete":
        del parent[last]
    elif op == "wrong":
        parent[last] = copy.deepcopy(rng.choice(WRONG_VALUES))
    elif op == "rename" and isinstance(last, str):
        parent[last + "_"] = parent.pop(last)
    elif op == "shape":
        v = parent[last]
        parent[last] = ((v[:-1] if v and rng.random() < 0.5 else [*v, v[0] if v else 0])
                        if isinstance(v, list) else [v])
    else:
        parent[last] = rng.choice([float("nan"), float("inf"), -float("inf")])
    return doc, f"{op} at {list(path)}"


def mutate_png(data: bytes, rng: random.Random) -> tuple[bytes | None, str]:
    op = rng.choice(["truncate", "flip", "empty", "delete", "resize", "garbage"])
    if op == "truncate":
        return data[: rng.randrange(0, len(data))], op
    if op == "flip":
        b = bytearray(data)
        i = rng.randrange(len(b))
        b[i] ^= 1 << rng.randrange(8)
        return bytes(b), f"flip byte {i}"
    if op == "empty":
        return b"", op
    if op == "delete":
        return None, op
    if op == "resize":
        blank = np.zeros((rng.randint(1, 50), rng.randint(1, 50)), np.uint8)
        return cv2.imencode(".png", blank)[1].tobytes(), op
    return bytes(rng.randrange(256) for _ in range(rng.randint(1, 200))), op


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz") / "ref"
    write_referencing(root)
    assert validate_folder(root) == []
    return root


def test_validate_never_raises_and_reports_every_mutation(good, tmp_path, capsys):
    root = tmp_path / "ref"
    shutil.copytree(good, root)
    originals = {f.name: f.read_bytes() for f in root.iterdir()}
    docs = {name: json.loads(originals[name]) for name in ("state.json", "dataset.json", "run0.json")}
    recomputed = reported = 0
    exit_codes: dict[tuple[bytes, bytes], int] = {}
    for i in range(N_MUTATIONS):
        rng = random.Random(i)
        target = rng.choices(["state.json", "dataset.json", "run0.json", "run0.png", "text"],
                             [6, 1, 1, 2, 1])[0]
        if target == "run0.png":
            data, what = mutate_png(originals["run0.png"], rng)
            if data is None:
                (root / target).unlink()
            else:
                (root / target).write_bytes(data)
        elif target == "text":  # broken JSON text
            target = rng.choice(["state.json", "dataset.json", "run0.json"])
            text = originals[target]
            (root / target).write_bytes(text[: rng.randrange(len(text))])
            what = "truncated JSON text"
        else:
            doc, what = mutate_json(docs[target], rng)
            (root / target).write_text(json.dumps(doc))
        problems = validate_folder(root)  # must not raise, whatever the mutation
        assert all(isinstance(p, Problem) and p.file and p.path.startswith("$") for p in problems)
        if problems:
            reported += 1
            assert all(isinstance(p.message, str) and p.message for p in problems)
        else:
            # a harmless mutation (e.g. a renamed optional key): recompute gives a documented exit code
            recomputed += 1
            key = ((root / "state.json").read_bytes(), (root / "run0.png").read_bytes())
            if key not in exit_codes:
                exit_codes[key] = ctl.main(["recompute", str(root)])
                capsys.readouterr()
            assert exit_codes[key] in (0, 1, 2, 5), (i, target, what, exit_codes[key])
        (root / target).write_bytes(originals[target])
    assert reported + recomputed == N_MUTATIONS
    print(f"{reported} mutations reported, {recomputed} valid ({len(exit_codes)} distinct inputs recomputed)")
    assert reported > 0.8 * N_MUTATIONS, (reported, recomputed)


def test_non_finite_numbers_are_reported_where_they_are(good, tmp_path):
    root = tmp_path / "ref"
    shutil.copytree(good, root)
    state = json.loads((root / "state.json").read_text())
    state["obs"]["sigma_t_mm"] = math.inf
    (root / "state.json").write_text(json.dumps(state))
    assert any(p.path == "$.obs.sigma_t_mm" and "not a finite number" in p.message
               for p in validate_folder(root))


def _png(width: int, height: int, idat: bytes) -> bytes:
    def chunk(tag: bytes, body: bytes) -> bytes:
        return (struct.pack(">I", len(body)) + tag + body
                + struct.pack(">I", zlib.crc32(tag + body) & 0xFFFFFFFF))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", idat) + chunk(b"IEND", b""))


def test_hostile_files_give_problems_not_crashes(good, tmp_path):
    root = tmp_path / "ref"
    shutil.copytree(good, root)
    (root / "run0.json").write_text("[" * 100000 + "]" * 100000)  # deeper than json's recursion limit
    nested: list = []
    for _ in range(70):
        nested = [nested]
    (root / "result.json").write_text(json.dumps({"a": nested}))
    (root / "run0.png").write_bytes(_png(100000, 100000, zlib.compress(bytes(10 ** 6))))  # claims 10 GB
    problems = {p.file: p.message for p in validate_folder(root)}
    assert "nested more than 64 levels" in problems["result.json"]
    assert "nested more than 64 levels" in problems["run0.json"] or "not valid JSON" in problems["run0.json"]
    assert "implausible size" in problems["state.json"]
    # inflates far too big
    (root / "run0.png").write_bytes(_png(1280, 960, zlib.compress(bytes(50 * 10 ** 6))))
    assert any("a 1280x960 image needs" in p.message for p in validate_folder(root))
