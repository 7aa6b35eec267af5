"""What the worker does with a procedure's saved result on the robot, per declared procedure.

Referencing with a verdict other than ``fail`` becomes the active calibration; an
intrinsics result is kept with its dataset and installed as the camera model (at once on
``ok``, after the operator's yes on ``warn``); an experiment asked to ``store_bias`` writes
its fitted robot-frame bias into the active calibration. Each adds at most one message.
"""
from __future__ import annotations

from typing import Any, Callable

from daemon.bus.procedures import EXPERIMENT, INTRINSICS, REFERENCING, Hooks
from daemon.bus.storage import atomic_write_json, calibration_dir
from daemon.worker.compensations import store_bias
from daemon.worker.job import JobContext
from daemon.worker.store import add_message, install_camera_model

FINISH: Hooks[Callable[[JobContext, dict[str, Any]], dict[str, Any]]] = Hooks("finish", optional=True)


@FINISH.on(REFERENCING)
def _activate(ctx: JobContext, result: dict[str, Any]) -> dict[str, Any]:
    if result.get("verdict") != "fail":
        atomic_write_json(calibration_dir(ctx.data_dir) / "active.json", result)
    return result


@FINISH.on(INTRINSICS)
def _install_model(ctx: JobContext, result: dict[str, Any]) -> dict[str, Any]:
    atomic_write_json(ctx.root / "camera_model.json", result["camera_model"])  # kept with the dataset
    return add_message(ctx.root, ctx.data_dir, result, install_camera_model(ctx, result))


@FINISH.on(EXPERIMENT)
def _store_bias(ctx: JobContext, result: dict[str, Any]) -> dict[str, Any]:
    if not ctx.params.store_bias:
        return result
    try:
        note = store_bias(ctx.data_dir, result)
    except ValueError as exc:
        note = f"robot-frame bias NOT stored: {exc}"
    return add_message(ctx.root, ctx.data_dir, result, note)


def finish(ctx: JobContext, result: dict[str, Any]) -> dict[str, Any]:
    """The procedure's finish, if it has one; the result as finally stored."""
    step = FINISH.get(ctx.procedure)
    return result if step is None else step(ctx, result)
