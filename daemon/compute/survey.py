"""The plate survey's workflow: a folder of photographs + the plate's design → a surveyed plate.json.

Runs where the photographs are (``ritactl plate survey`` on the operator's laptop, like
``ritactl recompute``): the survey needs no robot, and a set of 24 MP photographs is
hundreds of MB that the bus would only carry back and forth. The computation is
:func:`calibration.plate_survey.run_survey`; this module reads the files and names
the bad one when something is wrong.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np

from calibration.errors import CalibrationError  # noqa: F401 - re-exported for ritactl plate survey
from calibration.plate import NEST_NAMES, Plate
from calibration.plate_survey import Progress, run_survey

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".tif", ".tiff")
#: verdict "ok" needs every surveyed seat's 3-D 1σ within this (the survey's acceptance: 50 µm)
SIGMA_OK_MM = 0.05


def load_images(folder: Path, progress: Progress | None = None) -> dict[str, np.ndarray]:
    """``{file name: RGB image}`` of each photograph in ``folder`` (sorted); ValueError names a bad file."""
    import cv2

    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder of photographs")
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTS)
    if not files:
        raise ValueError(f"{folder}: no photographs ({', '.join(IMAGE_EXTS)}) found")
    out = {}
    for i, p in enumerate(files):
        if progress:
            progress(i / len(files), f"read {p.name} ({i + 1}/{len(files)})")
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError(f"{p}: not a readable image")
        if img.ndim != 3 or img.shape[2] not in (3, 4):
            raise ValueError(f"{p}: a {'grey' if img.ndim == 2 else str(img.shape)} image; the survey needs "
                             f"colour photographs to tell the red, green and blue rings apart")
        out[p.name] = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2RGB)
    return out


def survey_plate(folder: Path, plate: dict[str, Any], source: str = "plate",
                 progress: Callable[[float, str], None] | None = None) -> dict[str, Any]:
    """The surveyed plate definition (JSON object) with ``survey.verdict`` ok / warn.

    ``progress(percent, step)``, when given, hears each photograph read (0–20 %) and detected (20–90 %).
    """
    def part(lo: float, hi: float) -> Progress | None:
        return None if progress is None else lambda f, step: progress(lo + (hi - lo) * f, step)

    design = Plate.from_dict(plate, source)
    result = run_survey(load_images(folder, part(0, 20)), design, part(20, 90))
    sig = {c: float(np.linalg.norm(result.plate.nests_sigma_mm[c])) for c in NEST_NAMES}
    worst = max(sig, key=lambda c: sig[c])
    verdict = "ok" if sig[worst] <= SIGMA_OK_MM else "warn"
    result.report["verdict"] = verdict
    result.report["message"] = (f"largest nest uncertainty {sig[worst] * 1000:.0f} µm (1σ, 3-D, {worst}); "
                                f"{'within' if verdict == 'ok' else 'above'} {SIGMA_OK_MM * 1000:.0f} µm"
                                + ("" if verdict == "ok" else ": add photographs from more directions"))
    result.report["source_folder"] = str(folder)
    return result.plate.to_dict()
