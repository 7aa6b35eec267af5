"""Result files of a procedure: versioned JSON, an OpenCV FileStorage YAML export and, for an experiment,
its report and plot; the same for a live run and for ``ritactl recompute --out``."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from daemon.bus.procedures import EXPERIMENT, Hooks
from daemon.bus.storage import atomic_write_bytes, atomic_write_json, atomic_write_text


def write_yaml(path: Path, result: dict[str, Any]) -> None:
    """OpenCV FileStorage YAML with the matrices a C++/HALCON user would want, written atomically."""
    import cv2

    # built in memory, so the file itself goes through the one atomic write
    flags = cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML
    fs = cv2.FileStorage(".yaml", flags)
    try:
        for key in ("job", "procedure", "software", "plate_id", "verdict", "created"):
            if result.get(key) is not None:
                fs.write(key, str(result[key]))
        for key in ("rob_H_cam", "rob_H_scn"):
            if result.get(key) is not None:
                fs.write(key, np.array(result[key], dtype=np.float64))
        if result.get("scs"):
            fs.write("scn_H_cam", np.array(result["scs"]["scn_H_cam"], dtype=np.float64))
        model = result.get("camera_model")
        if model:
            fs.write("camera_matrix", np.array(model["K"], dtype=np.float64))
            fs.write("dist_coeffs", np.array(model["dist"], dtype=np.float64).reshape(1, -1))
            fs.write("image_size", np.array(model["size"], dtype=np.int32).reshape(1, 2))
        mark = result.get("mark")
        if mark:
            fs.write("mark_abs_xyz", np.array(mark["abs_xyz"], dtype=np.float64).reshape(1, 3))
    except BaseException:
        fs.release()
        raise
    atomic_write_text(path, fs.releaseAndGetString())


#: an experiment's report files (docs/datasets.md, "Experiment report")
REPORT_FILES = ["report.md", "report.csv", "report_metrics.csv", "report_stops.csv", "clusters.png"]


def _experiment_report(root: Path, result: dict[str, Any]) -> None:
    from daemon.compute.report import plot_clusters
    from daemon.compute.report_header import header_markdown
    from daemon.compute.report_shifts import compensation_effects, left_out_metrics, plain_metrics
    from daemon.compute.report_tables import metrics_csv, stops_csv

    files = ("\n## Files\n\n- `report.csv`: the table above, one row per direction and All\n"
             "- `report_metrics.csv`: one row per figure, with its goal met or MISSED\n"
             "- `report_stops.csv`: one row per stop: heading, mark, σ and its parts, each compensation and "
             "how far it moved the mark\n"
             "- `clusters.png`: the stops relative to their mean, with this header\n")
    # every file made before the first is written: a failing plot (no matplotlib) leaves no partial report
    table = "\n## The paper's table\n\n" + result["table_markdown"]
    effects = compensation_effects(result, result.get("dataset") or root)
    plain = plain_metrics(result, effects)
    compared = {"why": effects.why, "plain": plain,
                "left_out": left_out_metrics(result, effects) if plain else {}}
    texts = {"report.md": header_markdown(result, compared) + table + files,
             "report.csv": result["table_csv"], "report_metrics.csv": metrics_csv(result, plain),
             "report_stops.csv": stops_csv(result, effects.shifts)}
    png = plot_clusters(result, compared)
    for name, text in texts.items():
        atomic_write_text(root / name, text)
    atomic_write_bytes(root / "clusters.png", png)


#: a procedure's files besides result.json/.yaml: (their names, the writer)
EXTRA_FILES: Hooks[Callable[[Path, dict[str, Any]], None]] = Hooks("result files", optional=True)
EXTRA_FILES.on(EXPERIMENT)(_experiment_report)
_NAMES = {EXPERIMENT.name: REPORT_FILES}


def write_result_files(root: Path, result: dict[str, Any],
                       dataset: Path | str | None = None) -> dict[str, Any]:
    """result.json, result.yaml and the procedure's own files (an experiment: :data:`REPORT_FILES`).

    The same files for a live run and for ``ritactl recompute --out``; returns the
    result as written (with ``created``, ``dataset`` and, with own files, ``files``).
    """
    root = Path(root)
    result = {**result, "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
              "dataset": str(dataset if dataset is not None else root)}
    extra = EXTRA_FILES.get(result["procedure"])
    if extra is not None:
        result["files"] = list(_NAMES[result["procedure"]])
    atomic_write_json(root / "result.json", result)
    write_yaml(root / "result.yaml", result)
    if extra is not None:
        extra(root, result)
    return result
