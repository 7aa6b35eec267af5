"""The worker's results on the robot: the result files (daemon/compute/files.py), the active
calibration and history."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from daemon.bus.storage import atomic_write_json, calibration_dir
from daemon.compute.files import write_result_files
from daemon.worker.job import JobContext


def save_result(root: Path, data_dir: Path, result: dict[str, Any]) -> dict[str, Any]:
    """Write the result files into the dataset and keep the history copy (daemon/worker/finish.py
    does the rest)."""
    result = write_result_files(root, result)
    atomic_write_json(calibration_dir(data_dir) / "history" / f"{result['job']}.json", result)
    return result


def add_message(root: Path, data_dir: Path, result: dict[str, Any], message: str) -> dict[str, Any]:
    """Append a message to a saved result (result.json and its history copy), atomically."""
    result = {**result, "messages": [*(result.get("messages") or []), message]}
    atomic_write_json(Path(root) / "result.json", result)
    atomic_write_json(calibration_dir(data_dir) / "history" / f"{result['job']}.json", result)
    return result


def install_camera_model(ctx: JobContext, result: dict[str, Any], answer_within_s: float = 900.0) -> str:
    """Make an intrinsics result the robot's camera model: at once on ``ok``, after a yes on ``warn``.

    Returns one line for the result's messages saying what happened and, when the
    model was not installed, how to install it anyway.
    """
    src = Path(result["dataset"]) / "camera_model.json"
    target = calibration_dir(ctx.data_dir) / "camera_model.json"
    later = (f"to install it later: copy {src} to {target} on the robot, or pass it to a job with "
             f"--camera-model FILE")
    verdict = result.get("verdict")
    if verdict == "warn":
        findings = "; ".join(result.get("messages") or []) or "see the report"
        try:
            answer = ctx.ask(f"the camera model has verdict warn ({findings}). "
                             f"Install it as the robot's camera model for later jobs?",
                             ["install", "skip"], timeout_s=answer_within_s)
        except TimeoutError:
            answer = "no answer"
        if answer != "install":
            return f"camera model NOT installed (verdict warn, answer: {answer}); {later}"
    elif verdict != "ok":
        return f"camera model NOT installed (verdict {verdict}); {later}"
    atomic_write_json(target, result["camera_model"])
    return f"camera model installed as {target}"
