"""The error-budget bar plot of bench_accuracy.py, drawn with OpenCV (no plotting dependency).

Three panels (enclosing diameter, pairwise cluster means, absolute error RMS), one horizontal
bar per case at its median with a whisker to its p95, the goal as a red line and the
paper's figure as a blue line.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from daemon.bus.storage import atomic_write_bytes

PANELS = (("enclosing_mm", "Enclosing diameter [mm]"), ("pairwise_mm", "Pairwise cluster means [mm]"),
          ("abs_rms_mm", "Absolute error RMS vs truth [mm]"))
FONT = cv2.FONT_HERSHEY_SIMPLEX
LABEL_W, PANEL_W, ROW_H, TOP, PAD = 330, 300, 34, 80, 20
BAR, WHISKER, GOAL, PAPER = (90, 140, 60), (40, 40, 40), (40, 40, 220), (200, 120, 30)


def _text(img: np.ndarray, text: str, org: tuple[int, int], colour: tuple[int, int, int]) -> None:
    """Text on a white box, so lines behind it do not cross it."""
    (w, h), base = cv2.getTextSize(text, FONT, 0.38, 1)
    cv2.rectangle(img, (org[0] - 1, org[1] - h - 2), (org[0] + w + 1, org[1] + base), (255, 255, 255), -1)
    cv2.putText(img, text, org, FONT, 0.38, colour, 1, cv2.LINE_AA)


def _panel(img: np.ndarray, x0: int, key: str, title: str, summary: dict, goal: float | None,
           paper: float | None) -> None:
    vmax = max([s[key][1] for s in summary.values()] + [goal or 0, paper or 0]) * 1.25
    sx = (PANEL_W - 2 * PAD) / vmax
    cv2.putText(img, title, (x0 + 4, 28), FONT, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    bottom = TOP + len(summary) * ROW_H
    for value, colour, name, dy in ((goal, GOAL, "goal", 0), (paper, PAPER, "paper", 12)):
        if value is not None:  # behind the bars
            x = x0 + PAD + int(value * sx)
            cv2.line(img, (x, TOP - 8 - dy), (x, bottom), colour, 2)
            _text(img, f"{name} {value:g}", (x + 3, TOP - 10 - dy), colour)
    for i, s in enumerate(summary.values()):
        y = TOP + i * ROW_H
        med, p95 = s[key]
        cv2.rectangle(img, (x0 + PAD, y), (x0 + PAD + int(med * sx), y + ROW_H - 12), BAR, -1)
        yc = y + (ROW_H - 12) // 2
        cv2.line(img, (x0 + PAD + int(med * sx), yc), (x0 + PAD + int(p95 * sx), yc), WHISKER, 1)
        _text(img, f"{med:.3f}", (x0 + PAD + int(p95 * sx) + 4, yc + 5), (0, 0, 0))
    cv2.line(img, (x0 + PAD, bottom), (x0 + PANEL_W - PAD, bottom), (0, 0, 0), 1)


def budget_png(summary: dict[str, dict], goals: dict[str, float], paper: dict[str, float],
               path: Path) -> None:
    """Write the plot of ``summary`` (case label -> metric -> (median, p95)) to ``path``."""
    h = TOP + len(summary) * ROW_H + 40
    img = np.full((h, LABEL_W + PANEL_W * len(PANELS), 3), 255, np.uint8)
    for i, label in enumerate(summary):
        cv2.putText(img, label, (8, TOP + i * ROW_H + 16), FONT, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for j, (key, title) in enumerate(PANELS):
        _panel(img, LABEL_W + j * PANEL_W, key, title, summary, goals.get(key), paper.get(key))
    cv2.putText(img, "bar: median over seeds, whisker: p95; "
                "red: goal (paper+imu, default compensation, at p95); "
                "blue: the paper's glass plate", (8, h - 14), FONT, 0.4, (60, 60, 60), 1, cv2.LINE_AA)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise RuntimeError(f"could not encode {path}")
    atomic_write_bytes(path, buf.tobytes())
