"""The guided intrinsics steps without ritad: a bad view is asked for again with its reason, a
repeated view is refused, a skipped one is recorded, and a resumed job asks only for the rest."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.board import DEFAULT_BOARD, Board
from calibration.intrinsics_recipe import RECIPE
from calibration.target import make_board
from daemon.worker.guided_intrinsics import SETUP, guided_intrinsics as intrinsics
from daemon.bus.procedures import INTRINSICS
from daemon.worker.job import JobContext, StepFailed

SIZE = (640, 480)


def board_image(shift: float = 0.0) -> np.ndarray:
    """The board print filling most of the image, moved by ``shift`` px (a flat synthetic view)."""
    img = make_board(Board.from_dict(DEFAULT_BOARD)).generateImage(SIZE, marginSize=40, borderBits=1)
    H = np.float64([[0.9, 0, 30 + shift], [0, 0.9, 20 + shift / 2], [0, 0, 1]])
    return cv2.warpPerspective(img, H, SIZE, borderValue=200)


class Ctx:
    """Just what the procedure uses of a JobContext; ``answers`` and ``images`` are the operator's."""

    procedure = INTRINSICS.name
    definition = JobContext.definition  # the job's file, else the installed one: the product's own

    def __init__(self, tmp: Path, answers: list[str], images: list[np.ndarray]) -> None:
        self.params = INTRINSICS.resolve({"board": dict(DEFAULT_BOARD)})
        self.state: dict = {"done": []}
        self.obs: dict = {}
        self.data_dir = tmp
        self.answers, self.images, self.questions = answers, images, []

    def done(self, step: str) -> bool:
        return step in self.state["done"]

    def mark_done(self, step: str) -> None:
        self.state["done"].append(step)

    def checkpoint(self) -> None:
        pass

    def progress(self, *args, **kw) -> None:
        pass

    def ask(self, question: str, choices: list[str]) -> str:
        self.questions.append(question)
        return self.answers.pop(0) if self.answers else "skip"

    def capture_image(self, name: str):
        return f"{name}.png", {"shape": [SIZE[1], SIZE[0]]}, self.images.pop(0)


def test_bad_and_repeated_views_are_asked_again_and_skips_recorded(tmp_path) -> None:
    blank = np.full((SIZE[1], SIZE[0]), 128, np.uint8)
    images = [blank, board_image(), board_image(), board_image(2.0), board_image(60.0)]
    ctx = Ctx(tmp_path, ["ok"] * 6, images)
    intrinsics(ctx)
    q = ctx.questions
    assert q[0] == SETUP and "[view flat]" in q[1]
    assert q[2].startswith("view 1/12 [view flat]: view-00.png shows only 0 board corners")
    assert "view-01.png repeats the view accepted as flat" in q[4]
    assert "view-01-try2.png repeats the view accepted as flat" in q[5]  # moved 2 px: still the same view
    assert [v["image"] for v in ctx.obs["views"]] == ["view-00-try2.png", "view-01-try3.png"]
    assert ctx.obs["skipped"] == [s.key for s in RECIPE[2:]]
    assert ctx.state["view-00.tries"] == 2 and ctx.state["view-01.tries"] == 3

    ctx.answers, ctx.questions = [], []
    intrinsics(ctx)  # resumed: every step done, nothing asked
    assert ctx.questions == []


def test_a_bad_board_file_is_refused_before_the_operator_starts(tmp_path) -> None:
    ctx = Ctx(tmp_path, [], [])
    ctx.params = INTRINSICS.resolve({"board": {**DEFAULT_BOARD, "marker_mm": 5.0}})
    with pytest.raises(ValueError, match="marker_mm=5.0 must be in"):
        intrinsics(ctx)
    ctx = Ctx(tmp_path, [], [])
    ctx.params = INTRINSICS.resolve({})
    with pytest.raises(ValueError,
                       match="board.json does not exist: pass the board you hold with --board FILE"):
        intrinsics(ctx)
    assert ctx.questions == []


def test_a_view_that_stays_bad_fails_its_step_and_a_resume_asks_again(tmp_path) -> None:
    blank = np.full((SIZE[1], SIZE[0]), 128, np.uint8)
    ctx = Ctx(tmp_path, ["ok"] * 6, [blank] * 5)
    with pytest.raises(StepFailed, match="no usable image in 5 tries .last: view-00-try5.png shows only 0"):
        intrinsics(ctx)
    ctx.answers, ctx.images = ["ok"], [board_image()]
    intrinsics(ctx)  # resumed: the same view, under a new name
    assert ctx.obs["views"][0]["image"] == "view-00-try6.png"
