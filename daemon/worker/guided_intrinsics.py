"""The guided ``intrinsics`` procedure: the operator presents a hand-held board, view by view.

Each view of :data:`calibration.intrinsics_recipe.RECIPE` is one prompt saying how to
hold the board (it names the view as ``[view KEY]``); the frame is captured and checked
at once: enough board corners, and not a repeat of an earlier view. A bad view is asked
for again with the reason; ``skip`` leaves a view out (the calculation then says whether
the set still separates the focal length from the distance, and which view to add).
Every accepted view is a completed step, so a resumed job asks only for the missing ones.
The result is computed from the stored images by ``daemon.compute.procedures.compute_intrinsics``
(as ``ritactl recompute`` does).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from calibration.board import Board, detect_board_corners
from calibration.image import to_grey
from calibration.intrinsics_recipe import CORNERS, RECIPE, ViewSpec, reaches_corner, same_as
from daemon.worker.job import JobContext, StepFailed

#: board corners a view needs (of 88 on the default board): fewer cannot pin its pose and tilt
MIN_VIEW_CORNERS = 20
#: presentations of one view before the step fails (a resume asks MAX_TRIES more times)
MAX_TRIES = 5
SETUP = ("put the robot on its calibration stand (camera free, nothing within 100 mm below the lens) "
         "and have the calibration board ready; answer 'ok'")


def _board(ctx: JobContext) -> Board:
    """The board definition: the job's ``board`` parameter, else the robot's installed board.json."""
    if "board" not in ctx.obs:
        d = ctx.definition("board", "pass the board you hold with --board FILE (docs/operations.md, "
                                    "Intrinsic calibration)")
        Board.from_dict(d, source="board file")  # refuse a bad file before the operator starts
        ctx.obs["board"] = d
        ctx.checkpoint()
    return Board.from_dict(ctx.obs["board"], source="state.json: obs.board")


def _present(ctx: JobContext, name: str, spec: ViewSpec, board: Board, label: str,
             previous: list[tuple[np.ndarray, np.ndarray, str]]) -> dict[str, Any] | None:
    """Ask for one view until it is good (or skipped); the stored entry, None when skipped."""
    reason = ""
    for _ in range(MAX_TRIES):
        tries = int(ctx.state.get(f"{name}.tries", 0))  # over every run of the job: names never repeat
        answer = ctx.ask(f"{label} [view {spec.key}]: {reason}{spec.instruction()}. "
                         f"Answer 'ok' when the board is steady, or 'skip' to leave this view out",
                         ["ok", "skip"])
        if answer == "skip":
            return None
        ctx.state[f"{name}.tries"] = tries + 1
        file, header, pixels = ctx.capture_image(name if tries == 0 else f"{name}-try{tries + 1}")
        grey = to_grey(pixels, header.get("pixel_format"))  # Bayer: demosaiced
        ids, uv = detect_board_corners(grey, board)
        again = (same_as(ids, uv, [p[:2] for p in previous], pixels.shape[1])
                 if len(ids) >= MIN_VIEW_CORNERS else None)
        if len(ids) < MIN_VIEW_CORNERS:
            reason = (f"{file} shows only {len(ids)} board corners (need {MIN_VIEW_CORNERS}): "
                      f"bring the whole board into view and try again. ")
        elif again is not None:
            reason = (f"{file} repeats the view accepted as {previous[again][2]} (it adds nothing): "
                      f"change the tilt as described and try again. ")
        elif spec.key in CORNERS and not reaches_corner(uv, (pixels.shape[1], pixels.shape[0]), spec.key):
            reason = (f"in {file} the board does not reach the image's {spec.key} corner "
                      f"(the lens distortion is largest there): "
                      f"move it further into that corner and try again. ")
        else:
            return {"image": file, "header": header, "key": spec.key, "n_corners": int(len(ids)),
                    "ids": ids.tolist(), "uv": np.round(uv, 3).tolist()}
        ctx.checkpoint()
    raise StepFailed(f"no usable image in {MAX_TRIES} tries (last: {reason.strip()}); "
                     f"`ritactl resume` asks again")


def guided_intrinsics(ctx: JobContext) -> None:
    """Set-up prompt, then one prompt + capture + check per recipe view."""
    board = _board(ctx)
    if not ctx.done("setup"):
        ctx.progress("set-up", 2, "the operator")
        ctx.ask(SETUP, ["ok"])
        ctx.mark_done("setup")
    views = ctx.obs.setdefault("views", [])
    skipped = ctx.obs.setdefault("skipped", [])
    n = len(RECIPE)
    for j, spec in enumerate(RECIPE):
        name = f"view-{j:02d}"
        if ctx.done(name):
            continue
        ctx.progress(f"view {j + 1}/{n} ({spec.key})", 5 + 85 * j / n, "the operator presents the board")
        previous = [(np.asarray(v["ids"]), np.asarray(v["uv"]), v["key"]) for v in views]
        entry = _present(ctx, name, spec, board, f"view {j + 1}/{n}", previous)
        if entry is None:
            skipped.append(spec.key)
        else:
            views.append(entry)
        ctx.mark_done(name)
    ctx.progress("calibrate the camera", 92, "")
