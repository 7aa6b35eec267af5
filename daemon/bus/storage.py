"""Crash-safe files and dataset folders.

Every file is written to a temporary name in the same directory, flushed, fsynced
and renamed over the target, then the directory is fsynced: after a crash a reader
sees the old file or the new one, never half of one. A dataset is a folder with a
``dataset.json`` manifest plus one entry per capture (lossless PNG image and a
JSON sidecar that a person can read without this project); see docs/datasets.md.
"""
from __future__ import annotations

import json
import os
import re
import tempfile
import time
from pathlib import Path
from typing import Any

DATASET_SCHEMA = 1
_SAFE = re.compile(r"[^A-Za-z0-9._-]+")


def fsync_dir(path: Path) -> None:
    """Make a rename in ``path`` durable; the file's own fsync does not cover its directory entry."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # Windows cannot open a directory; its renames need no separate flush
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write_bytes(path: Path, data: bytes | memoryview, mode: int | None = None) -> Path:
    """Write ``data`` to ``path`` atomically: temp file beside it, fsync, rename, fsync the folder.

    The project's one atomic write: every program, the simulator and the benchmarks use it
    (calibration/ writes no files). The file is private (0600, from mkstemp) unless ``mode`` says
    otherwise, e.g. 0644 for a public key that root writes and the daemon's user must read.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    fsync_dir(path.parent)
    return path


def atomic_write_text(path: Path, text: str, mode: int | None = None) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"), mode)


def atomic_write_json(path: Path, obj: Any) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=False, default=_json_default) + "\n")


def _json_default(o: Any) -> Any:
    if hasattr(o, "tolist"):
        return o.tolist()
    if hasattr(o, "item"):
        return o.item()
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def safe_name(text: str, limit: int = 100) -> str:
    """A file-name-safe version of ``text``, cut to ``limit`` characters (file names have a size limit).

    Leading and trailing dots go too, so "." and ".." never name a folder (no climbing out).
    """
    return _SAFE.sub("-", text).strip("-.")[:limit].rstrip("-.") or "x"


def encode_image(pixels: Any, fmt: str = ".png") -> bytes:
    """Lossless PNG/TIFF bytes for an 8/16-bit mono or colour image (OpenCV, imported lazily).

    Colour frames are R, G, B(, a) in memory (docs/datasets.md, "Images"); OpenCV writes
    B, G, R, so they are swapped here and the file holds true RGB(A).
    """
    import cv2  # noqa: PLC0415 - keeps ritactl free of OpenCV

    if getattr(pixels, "ndim", 0) == 3 and pixels.shape[2] in (3, 4):
        pixels = cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR if pixels.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
    ok, buf = cv2.imencode(fmt, pixels)
    if not ok:
        raise ValueError(f"could not encode a {getattr(pixels, 'shape', '?')} image as {fmt}")
    return buf.tobytes()


class Dataset:
    """A self-describing folder of captures; see docs/datasets.md."""

    def __init__(self, root: Path, kind: str = "captures", meta: dict[str, Any] | None = None) -> None:
        self.root = Path(root)
        self.manifest_path = self.root / "dataset.json"
        if self.manifest_path.exists():
            self.manifest = json.loads(self.manifest_path.read_text())
        else:
            self.manifest = {"schema": DATASET_SCHEMA, "kind": kind, "created_ns": time.time_ns(),
                             "meta": meta or {}, "entries": []}
            atomic_write_json(self.manifest_path, self.manifest)

    @classmethod
    def create(cls, parent: Path, kind: str, meta: dict[str, Any] | None = None) -> "Dataset":
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        root = Path(parent) / f"{stamp}-{safe_name(kind)}"
        n = 1
        while root.exists():
            n += 1
            root = Path(parent) / f"{stamp}-{safe_name(kind)}-{n}"
        return cls(root, kind, meta)

    def add_entry(self, name: str, meta: dict[str, Any], image: Any = None,
                  image_format: str = ".png") -> Path:
        """Store one capture: image file (if any) + JSON sidecar; update the manifest last."""
        name = safe_name(name)
        entry: dict[str, Any] = {"name": name, "json": f"{name}.json"}
        if image is not None:
            img_name = f"{name}{image_format}"
            atomic_write_bytes(self.root / img_name, encode_image(image, image_format))
            entry["image"] = img_name
            meta = {**meta, "image_file": img_name}
        atomic_write_json(self.root / entry["json"], meta)
        self.manifest["entries"].append(entry)
        atomic_write_json(self.manifest_path, self.manifest)
        return self.root / entry["json"]


def tracker_point_dict(point: dict[str, Any], abs_H_trk: Any) -> dict[str, Any]:
    """A tracker point (tracker frame x y z) with ``abs_xyz`` and the ``abs_H_trk`` that gave it.

    Both frames are stored so a reader can check one against the other
    (docs/datasets.md, "Tracker points"); without ``abs_H_trk`` only x y z are known.
    """
    if abs_H_trk is None:
        return point
    H = [[float(v) for v in row] for row in abs_H_trk]
    xyz = (point["x"], point["y"], point["z"])
    abs_xyz = [sum(H[i][j] * xyz[j] for j in range(3)) + H[i][3] for i in range(3)]
    return {**point, "abs_xyz": abs_xyz, "abs_H_trk": H}


def save_capture(data_dir: Path, parts: dict[str, Any], label: str, dataset: str | None,
                 meta: dict[str, Any]) -> Path:
    """Store a capture (camera Frame / TrackerPoint / RobotState, any subset) as a dataset entry.

    ``dataset`` names a folder under ``data_dir/datasets`` (created if new); None uses
    the day's ``captures`` dataset. Returns the entry's JSON path.
    """
    base = Path(data_dir) / "datasets"
    if dataset:
        root = base / safe_name(dataset)
        ds = Dataset(root, kind="captures", meta=meta)
    else:
        ds = Dataset(base / time.strftime("%Y%m%d-captures", time.gmtime()), kind="captures", meta=meta)
    entry: dict[str, Any] = {"label": label, "saved_ns": time.time_ns()}
    frame = parts.get("camera")
    if frame is not None:
        entry["camera"] = frame.header()
    if parts.get("tracker") is not None:
        entry["tracker"] = tracker_point_dict(parts["tracker"].to_dict(), meta.get("abs_H_trk"))
    if parts.get("robot") is not None:
        entry["robot"] = parts["robot"].to_dict()
    if parts.get("at_exposure") is not None:
        entry["at_exposure"] = parts["at_exposure"]
    name = f"{len(ds.manifest['entries']):04d}-{label}"
    return ds.add_entry(name, entry, image=None if frame is None else frame.pixels)


def calibration_dir(data_dir: Path) -> Path:
    return Path(data_dir) / "calibration"


def read_results(data_dir: Path) -> dict[str, Any]:
    """The active calibration and the history of results (newest first), as stored by the worker."""
    cdir = calibration_dir(data_dir)
    active = None
    if (cdir / "active.json").exists():
        active = json.loads((cdir / "active.json").read_text())
    history = []
    for p in sorted((cdir / "history").glob("*.json"), reverse=True) if (cdir / "history").exists() else []:
        try:
            r = json.loads(p.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            history.append({"file": str(p), "error": f"unreadable: {exc}"})
            continue
        history.append({"file": str(p), "job": r.get("job"), "procedure": r.get("procedure"),
                        "verdict": r.get("verdict"), "created": r.get("created"),
                        "dataset": r.get("dataset")})
    return {"active": active, "history": history}
