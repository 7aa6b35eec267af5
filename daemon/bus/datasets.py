"""Dataset folders checked against their contract: JSON Schema files + the checks a schema cannot say.

The schemas (``daemon/bus/schemas/*.schema.json``, shipped as package data) describe every
file of a dataset folder; docs/datasets.md explains the conventions behind them.
:func:`validate_folder` reports every problem at once, each with its file and JSON
path, so a tool writing datasets can fix them in one pass. Beyond the schemas it
checks: numbers are finite, 4x4 transforms are rigid, ``abs_xyz = abs_H_trk · xyz``
where both are stored, and images exist, are complete PNGs and match their headers.

Pure Python + ``jsonschema``: ``ritactl validate`` runs on the operator's laptop without
numpy or OpenCV.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Iterator

from daemon.bus.procedures import BY_NAME
from daemon.bus.obs_checks import stream_problems
from daemon.bus.png_check import png_info

SCHEMA_FILES = ("common", "dataset", "capture", "state", "plate", "camera_model", "result", "board")
SCHEMA_BASE = "https://rita.invalid/schemas/"
#: |abs_xyz − abs_H_trk·xyz| above this is a mismatch (mm); stored values round-trip far below it
XYZ_TOLERANCE_MM = 1e-4
#: a stored rotation must be orthonormal to this (|RᵀR − I| max element)
ROTATION_TOLERANCE = 1e-6
_TRANSFORM_KEY = re.compile(r"^[a-z]+_H_[a-z]+$")
_MAX_MESSAGE = 200
#: JSON nested deeper than this is refused (datasets need < 10; deep nesting exhausts recursion)
MAX_DEPTH = 64


@dataclass(frozen=True)
class Problem:
    """One thing wrong in a dataset folder: which file, where in it (JSON path), what."""

    file: str
    path: str
    message: str

    def __str__(self) -> str:
        return f"{self.file}: {self.path}: {self.message}"

    def to_dict(self) -> dict[str, str]:
        return {"file": self.file, "path": self.path, "message": self.message}


class DatasetInvalid(ValueError):
    """A dataset folder breaks its contract; ``problems`` lists every finding."""

    def __init__(self, root: Path, problems: list[Problem]) -> None:
        self.root, self.problems = Path(root), problems
        head = "; ".join(str(p) for p in problems[:3])
        more = f" (+{len(problems) - 3} more)" if len(problems) > 3 else ""
        super().__init__(f"{root}: {len(problems)} problem(s): {head}{more}")


# --------------------------------------------------------------------------- schemas


def schema_text(name: str) -> str:
    """The text of a shipped schema file, e.g. ``schema_text("state")``."""
    return resources.files("daemon.bus.schemas").joinpath(f"{name}.schema.json").read_text(encoding="utf-8")


@lru_cache(maxsize=None)
def validator(name: str) -> Any:
    """A jsonschema validator for one schema file, its cross-file ``$ref``s resolved locally."""
    from jsonschema import Draft202012Validator
    from referencing import Registry, Resource

    docs = {n: json.loads(schema_text(n)) for n in SCHEMA_FILES}
    registry = Registry().with_resources((SCHEMA_BASE + f"{n}.schema.json", Resource.from_contents(d))
                                         for n, d in docs.items())
    return Draft202012Validator(docs[name], registry=registry)


def _json_path(parts: Any) -> str:
    out = "$"
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if re.fullmatch(r"[A-Za-z_][\w-]*", str(p))
                                                    else f"[{json.dumps(str(p))}]")
    return out


def _reason(err: Any) -> str:
    """The validator's reason in full; only a long quoted value inside it is shortened."""
    text = err.message
    shown = repr(err.instance)
    if len(text) > _MAX_MESSAGE and len(shown) > 40 and shown in text:
        text = text.replace(shown, shown[:37] + "...", 1)
    return text


def check_schema(doc: Any, name: str, file: str) -> list[Problem]:
    """Schema problems of ``doc``; a missing key is reported at its own path (``$.obs.runs[0].P1``)."""
    out = []
    for err in validator(name).iter_errors(doc):
        parts = list(err.absolute_path)
        if err.validator == "required":
            out += [Problem(file, _json_path([*parts, key]), "missing (required)")
                    for key in err.validator_value
                    if isinstance(err.instance, dict) and key not in err.instance]
        else:
            out.append(Problem(file, _json_path(parts), _reason(err)))
    return sorted(set(out), key=lambda p: (p.path, p.message))


# --------------------------------------------------------------------------- checks beyond the schema


def _walk(doc: Any, parts: tuple[Any, ...] = ()) -> Iterator[tuple[tuple[Any, ...], Any]]:
    yield parts, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _walk(v, (*parts, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _walk(v, (*parts, i))


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _matrix(v: Any, n: int) -> list[list[float]] | None:
    """``v`` as an n×n list of finite numbers, or None."""
    if not (isinstance(v, list) and len(v) == n and all(isinstance(r, list) and len(r) == n for r in v)):
        return None
    if not all(_is_num(x) and math.isfinite(x) for r in v for x in r):
        return None
    return v


def rigid_problem(H: list[list[float]]) -> str | None:
    """Why a 4×4 matrix is not a rigid transform, or None."""
    if any(abs(H[3][j] - (1.0 if j == 3 else 0.0)) > ROTATION_TOLERANCE for j in range(4)):
        return f"last row must be [0, 0, 0, 1], got {H[3]}"
    R = [r[:3] for r in H[:3]]
    for i in range(3):
        for j in range(3):
            dot = sum(R[k][i] * R[k][j] for k in range(3))
            if abs(dot - (1.0 if i == j else 0.0)) > ROTATION_TOLERANCE:
                return "rotation part is not orthonormal (RᵀR ≠ I)"
    det = (R[0][0] * (R[1][1] * R[2][2] - R[1][2] * R[2][1])
           - R[0][1] * (R[1][0] * R[2][2] - R[1][2] * R[2][0])
           + R[0][2] * (R[1][0] * R[2][1] - R[1][1] * R[2][0]))
    return None if det > 0 else "rotation part is a reflection (det < 0)"


def _point_problem(d: dict[str, Any], H: list[list[float]] | None) -> str | None:
    """Mismatch between a point's abs_xyz and abs_H_trk · (x, y, z), or None."""
    xyz: list[Any] = [d.get(k) for k in ("x", "y", "z")]  # JSON: numbers, checked below
    abs_xyz = d.get("abs_xyz")
    if H is None or not all(_is_num(v) and math.isfinite(v) for v in xyz):
        return None
    if not (isinstance(abs_xyz, list) and len(abs_xyz) == 3 and all(_is_num(v) and math.isfinite(v)
                                                                   for v in abs_xyz)):
        return None
    want = [sum(H[i][j] * xyz[j] for j in range(3)) + H[i][3] for i in range(3)]
    err = math.dist(want, abs_xyz)
    if err <= XYZ_TOLERANCE_MM:
        return None
    return (f"abs_xyz {abs_xyz} differs from abs_H_trk·(x, y, z) = {[round(v, 6) for v in want]} "
            f"by {err:.6g} mm (limit {XYZ_TOLERANCE_MM:g} mm)")


def check_values(doc: Any, file: str, abs_H_trk: Any = None) -> list[Problem]:
    """Non-finite numbers, non-rigid ``*_H_*`` transforms and tracker points whose two frames disagree.

    ``abs_H_trk`` (e.g. from dataset.json meta) applies to points that do not carry their own.
    """
    out = []
    default_H = _matrix(abs_H_trk, 4)
    for parts, v in _walk(doc):
        if isinstance(v, float) and not math.isfinite(v):
            out.append(Problem(file, _json_path(parts), f"{v} is not a finite number"))
        elif isinstance(v, dict):
            for k, m in v.items():
                H = _matrix(m, 4) if isinstance(k, str) and _TRANSFORM_KEY.match(k) else None
                why = None if H is None else rigid_problem(H)
                if why:
                    out.append(Problem(file, _json_path((*parts, k)), why))
            own = _matrix(v.get("abs_H_trk"), 4) if "abs_H_trk" in v else default_H
            why = _point_problem(v, own)
            if why:
                out.append(Problem(file, _json_path((*parts, "abs_xyz")), why))
    return out


# --------------------------------------------------------------------------- folders

_IMAGE_NAME = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._-]*\.png$")
_DEPTH = {"|u1": 8, "<u2": 16, ">u2": 16}
#: how each pixel format is stored (docs/datasets.md, "Images"): (PNG channels, bit depth)
STORED_AS = {"Mono8": (1, 8), "Mono12p": (1, 16), "Mono12Packed": (1, 16), "Mono16": (1, 16),
             "BayerRG8": (1, 8), "BayerRG12p": (1, 16), "RGB8": (3, 8), "RGBa8": (4, 8)}


def _load_json(root: Path, name: str, problems: list[Problem], required: bool = True) -> Any:
    path = root / name
    if not path.is_file():
        if required:
            problems.append(Problem(name, "$", "missing file"))
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        problems.append(Problem(name, "$", f"not valid JSON: {exc}"))
    except RecursionError:
        problems.append(Problem(name, "$", f"nested more than {MAX_DEPTH} levels deep"))
    except (OSError, UnicodeDecodeError) as exc:
        problems.append(Problem(name, "$", f"unreadable: {exc}"))
    else:
        if _depth(doc) <= MAX_DEPTH:
            return doc
        problems.append(Problem(name, "$", f"nested more than {MAX_DEPTH} levels deep"))
    return None


def _depth(doc: Any) -> int:
    """Nesting depth of a JSON document, without recursion."""
    deepest, stack = 0, [(doc, 1)]
    while stack:
        node, d = stack.pop()
        deepest = max(deepest, d)
        if isinstance(node, (dict, list)) and d <= MAX_DEPTH:
            stack.extend((v, d + 1) for v in (node.values() if isinstance(node, dict) else node))
    return deepest


class _Images:
    """Checks each referenced image once: complete PNG, and the size its header or model says."""

    def __init__(self, root: Path, problems: list[Problem]) -> None:
        self.root, self.problems = root, problems
        self.info: dict[str, tuple[int, ...] | str] = {}  # file -> png_info, or what is wrong

    def check(self, file: Any, where: str, path: str, header: Any = None,
              size_wh: Any = None, grey: bool = False) -> None:
        if not isinstance(file, str) or not _IMAGE_NAME.match(file):
            return  # the schema already reported the bad name
        if file not in self.info:
            try:
                self.info[file] = png_info(self.root / file) if (self.root / file).is_file() else "missing"
            except (OSError, ValueError) as exc:
                self.info[file] = str(exc)
        info = self.info[file]
        if isinstance(info, str):
            self.problems.append(Problem(where, path, f"image {file}: {info}"))
            return
        w, h, ch, depth = info
        if grey and not (ch == 1 and depth in (8, 16) or (ch, depth) == (3, 8)):
            self.problems.append(Problem(where, path, f"image {file} has {ch} channel(s) at {depth} bit; "
                                                      f"procedure images are 8- or 16-bit single-channel "
                                                      f"(mono or Bayer) or 8-bit RGB"))
        self._check_format(file, where, path, header, (ch, depth), grey)
        if isinstance(header, dict) and isinstance(header.get("shape"), list):
            shape, dtype = header["shape"], header.get("dtype")
            want = [h, w] if ch == 1 else [h, w, ch]
            if shape != want or (isinstance(dtype, str) and _DEPTH.get(dtype, depth) != depth):
                self.problems.append(Problem(
                    where, path, f"image {file} is {want} at {depth} bit but its header "
                                 f"says shape {shape}, dtype {header.get('dtype')}"))
        if isinstance(size_wh, list) and len(size_wh) == 2 and size_wh != [w, h]:
            self.problems.append(Problem(
                where, path, f"image {file} is {w}x{h} px but the camera model size is {size_wh}"))

    def _check_format(self, file: str, where: str, path: str, header: Any, got: tuple[int, int],
                      procedure: bool) -> None:
        """The PNG is stored as its header's pixel format says (none recorded: read as Mono8/16, RGB8)."""
        fmt = header.get("pixel_format") if isinstance(header, dict) else None
        if not isinstance(fmt, str):
            return
        want = STORED_AS.get(fmt)
        if want is None and procedure:
            self.problems.append(Problem(
                where, path, f"image {file}: pixel format {fmt!r} is not one the "
                             f"computation reads ({', '.join(STORED_AS)})"))
        elif want is not None and want != got:
            self.problems.append(Problem(
                where, path, f"image {file} has {got[0]} channel(s) at {got[1]} bit but "
                             f"pixel format {fmt} is stored with {want[0]} at {want[1]}"))


def _obs_images(obs: dict[str, Any]) -> Iterator[tuple[tuple[Any, ...], Any, Any]]:
    """(json path parts, image file, header) of every image a procedure's observations name."""
    for key in ("runs", "stops", "views"):
        items = obs.get(key)
        for i, item in enumerate(items if isinstance(items, list) else []):
            if isinstance(item, dict) and "image" in item:
                yield ("obs", key, i, "image"), item["image"], item.get("header")
    stop = obs.get("stop")
    if isinstance(stop, dict) and "image" in stop:
        yield ("obs", "stop", "image"), stop["image"], stop.get("header")


def _plate_problems(plate: Any, file: str, parts: tuple[Any, ...]) -> list[Problem]:
    """What the plate schema cannot say: markers smaller than squares."""
    if isinstance(plate, dict) and all(_is_num(plate.get(k)) for k in ("marker_mm", "square_mm")):
        if plate["marker_mm"] >= plate["square_mm"]:
            return [Problem(file, _json_path((*parts, "marker_mm")),
                            f"{plate['marker_mm']} must be smaller than square_mm ({plate['square_mm']})")]
    return []


def _model_problems(model: Any, file: str, parts: tuple[Any, ...]) -> list[Problem]:
    """What the camera model schema cannot say: fx, fy > 0 and a last row [0, 0, 1]."""
    K = _matrix(model.get("K"), 3) if isinstance(model, dict) else None
    if K is None:
        return []
    if K[0][0] <= 0 or K[1][1] <= 0 or K[2] != [0, 0, 1]:
        return [Problem(file, _json_path((*parts, "K")),
                        f"needs fx > 0, fy > 0 and a last row [0, 0, 1], got {K}")]
    return []


def _compensation_problems(obs: dict[str, Any]) -> list[Problem]:
    """The names of a comma list of compensations: JSON Schema checks the list's syntax, the names are
    the enum of common.schema.json's ``compensation`` (the one list of them in the bus)."""
    value = obs.get("compensation")
    if not isinstance(value, str) or value.strip() in ("none", "all"):
        return []
    known = json.loads(schema_text("common"))["$defs"]["compensation"]["enum"]
    unknown = [n.strip() for n in value.split(",") if n.strip() not in known]
    why = f"unknown compensation(s) {unknown} (known: {', '.join(known)}, or all/none)"
    return [Problem("state.json", "$.obs.compensation", why)] if unknown else []


def _check_state(state: Any, images: _Images, problems: list[Problem]) -> None:
    problems += check_schema(state, "state", "state.json") + check_values(state, "state.json")
    obs = state.get("obs") if isinstance(state, dict) else None
    if not isinstance(obs, dict):
        return
    problems += _plate_problems(obs.get("plate"), "state.json", ("obs", "plate"))
    problems += _plate_problems(obs.get("board"), "state.json", ("obs", "board"))  # the same rule for a board
    for key in ("camera_model", "initial_model"):
        problems += _model_problems(obs.get(key), "state.json", ("obs", key))
    problems += [Problem("state.json", _json_path(parts), msg) for parts, msg in stream_problems(obs)]
    problems += _compensation_problems(obs)
    calib = obs.get("calibration")
    scs = calib.get("scs") if isinstance(calib, dict) else None
    if isinstance(scs, dict):
        problems += _model_problems(scs.get("model"), "state.json", ("obs", "calibration", "scs", "model"))
    # the images of a referencing are taken by obs.camera_model, those of a mark by the calibration's
    proc = BY_NAME.get(str(state.get("procedure")))  # one whose own input is the camera model (referencing)
    own_model = proc is not None and proc.inputs.get("camera_model") == "camera_model"
    model = obs.get("camera_model") if own_model else (scs.get("model") if isinstance(scs, dict) else None)
    size = model.get("size") if isinstance(model, dict) else None
    for parts, file, header in _obs_images(obs):
        images.check(file, "state.json", _json_path(parts), header, size, grey=True)


def _check_manifest(root: Path, manifest: Any, images: _Images, problems: list[Problem]) -> None:
    problems += check_schema(manifest, "dataset", "dataset.json")
    meta = manifest.get("meta") if isinstance(manifest, dict) else None
    abs_H_trk = meta.get("abs_H_trk") if isinstance(meta, dict) else None
    problems += check_values(manifest, "dataset.json")
    entries = manifest.get("entries") if isinstance(manifest, dict) else None
    for i, e in enumerate(entries if isinstance(entries, list) else []):
        if (not isinstance(e, dict) or not isinstance(e.get("json"), str)
                or "/" in e["json"] or "\\" in e["json"]):
            continue
        side = _load_json(root, e["json"], problems)
        if side is not None:
            problems += check_schema(side, "capture", e["json"]) + check_values(side, e["json"], abs_H_trk)
        if "image" in e:
            header = side.get("camera") if isinstance(side, dict) else None
            images.check(e["image"], "dataset.json", _json_path(("entries", i, "image")), header)


def validate_folder(root: Path | str) -> list[Problem]:
    """Every problem of a dataset folder (empty list: clean). Never raises for bad content.

    A procedure folder (with ``state.json``) must be complete enough to recompute;
    its ``dataset.json`` and ``result.json`` are checked when present. A captures
    folder needs ``dataset.json``.
    """
    root = Path(root)
    if not root.is_dir():
        return [Problem(str(root), "$", "not a folder (does not exist or is a file)")]
    problems: list[Problem] = []
    images = _Images(root, problems)
    is_procedure = (root / "state.json").exists()
    manifest = _load_json(root, "dataset.json", problems, required=not is_procedure)
    if manifest is not None:
        _check_manifest(root, manifest, images, problems)
    if is_procedure:
        state = _load_json(root, "state.json", problems)
        if state is not None:
            _check_state(state, images, problems)
        result = _load_json(root, "result.json", problems, required=False)
        if result is not None:
            problems += check_schema(result, "result", "result.json") + check_values(result, "result.json")
    return problems


def check_file(doc: Any, name: str, file: str) -> list[Problem]:
    """Schema + value problems of one stand-alone document (``plate``, ``camera_model``, ``result``...)."""
    if _depth(doc) > MAX_DEPTH:
        return [Problem(file, "$", f"nested more than {MAX_DEPTH} levels deep")]
    out = check_schema(doc, name, file) + check_values(doc, file)
    if name in ("plate", "board"):
        out += _plate_problems(doc, file, ())
    return out + (_model_problems(doc, file, ()) if name == "camera_model" else [])
