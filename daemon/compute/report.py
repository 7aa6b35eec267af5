"""The experiment plot: every measured mark position per approach direction, like the paper's figure, with the
report's header beside it (daemon/compute/report_header.py) so that the picture alone says what it shows."""
from __future__ import annotations

import io
import textwrap
from typing import Any

import numpy as np

from daemon.bus.figures import EXPERIMENT_GOALS

#: the plot's header panel: characters a line, wrapped lines a value at most (report.md has them all)
WRAP, MAX_ROWS = 84, 3


def _header_text(result: dict[str, Any], compared: dict[str, Any] | None = None) -> str:
    """The header fields as wrapped text lines; a value cut short ends in ``… (report.md)``."""
    from daemon.compute.report_header import header

    lines = []
    for name, values in header(result, compared):
        lines.append(f"{name}:")
        for v in values:
            rows = textwrap.wrap(v, WRAP - 2, subsequent_indent="  ")
            if len(rows) > MAX_ROWS:
                rows = rows[:MAX_ROWS - 1] + [rows[MAX_ROWS - 1][:WRAP - 20] + " … (report.md)"]
            lines += [f"  {r}" for r in rows]
    return "\n".join(lines)


def _direction_label(name: str, mean_h: float, n: int) -> str:
    """``up: ψ = −0.3°, 5 stops`` (a mean heading that rounds to 0 prints as 0.0, never −0.0)."""
    shown = round(mean_h, 1) + 0.0  # + 0.0: -0.0 becomes 0.0
    return f"{name}: ψ = {shown:.1f}°, {n} stops"


def _clusters(ax: Any, rel: np.ndarray, ks: np.ndarray, headings: np.ndarray, names: list[str]) -> None:
    """One colour per direction: its stops as dots, its mean as a cross of the same colour."""
    import matplotlib.pyplot as plt

    from calibration.metrics import direction_name

    cmap = plt.get_cmap("tab10")
    for i, k in enumerate(list(dict.fromkeys(ks.tolist()))):
        sel = ks == k
        h = np.radians(headings[sel])
        mean_h = float(np.degrees(np.arctan2(np.sin(h).mean(), np.cos(h).mean())))  # circular: ±180° wraps
        name = names[i] if i < len(names) else direction_name(float(np.round(mean_h / 45.0) * 45.0))
        ax.scatter(rel[sel, 0], rel[sel, 1], s=22, color=cmap(i % 10), label=_direction_label(name, mean_h,
                                                                                            int(sel.sum())))
        m = rel[sel].mean(axis=0)
        ax.scatter([m[0]], [m[1]], marker="x", s=80, color=cmap(i % 10))


def _references(ax: Any, rel: np.ndarray, fit_xy: np.ndarray | None, enclosing_mm: float | None
                ) -> tuple[np.ndarray, float]:
    """The mean crosses' legend entry, the origin (the mean of all stops), the fitted mark M, the enclosing
    circle and the goal circle around its centre; that centre and the half-width the axes need (µm)."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from calibration.metrics import min_enclosing_circle
    from daemon.bus.figures import verdict

    ax.add_line(Line2D([], [], marker="x", ls="", color="black", label="direction mean (× in its colour)"))
    ax.scatter([0.0], [0.0], marker="+", s=160, color="black", label="mean of all stops (the origin)")
    if fit_xy is not None:
        ax.scatter([fit_xy[0]], [fit_xy[1]], marker="D", s=40, facecolors="none", color="black",
                   label="fitted mark M (M + R(ψ)·b)")
    c, r = min_enclosing_circle(rel)
    ax.add_patch(plt.Circle((float(c[0]), float(c[1])), r, fill=False, ls="--", color="grey",
                            label=f"enclosing circle, d = {2 * r:.0f} µm"))
    _, _, goal = EXPERIMENT_GOALS[0]
    met = verdict(goal.met(enclosing_mm))
    g = goal.limit * 1000.0 / 2  # the goal is a diameter in mm: the circle's radius in µm
    ax.add_patch(plt.Circle((float(c[0]), float(c[1])), g, fill=False, ls=":", lw=1.5,
                            color="tab:green" if met == "met" else "tab:red",
                            label=f"goal: enclosing d {goal.text()[5:]} ({met}), same centre"))
    return np.asarray(c, dtype=float), max(r, g) * 1.15


#: the header panel's margins (inches): above the header, between it and the legend, below the legend
TOP_IN, GAP_IN, BOTTOM_IN = 0.25, 0.15, 0.3


def _stack(fig: Any, text: Any, legend: Any) -> None:
    """The header text at the top right and the legend under it, never overlapping: the figure grows taller
    when both do not fit (their sizes are in points, the axes' in fractions of the figure)."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    text_in = text.get_window_extent(renderer).height / fig.dpi
    legend_in = legend.get_window_extent(renderer).height / fig.dpi
    width, height = fig.get_size_inches()
    height = max(height, TOP_IN + text_in + GAP_IN + legend_in + BOTTOM_IN)
    fig.set_size_inches(width, height)
    text.set_y(1.0 - TOP_IN / height)
    legend.set_bbox_to_anchor((0.575, 1.0 - (TOP_IN + text_in + GAP_IN) / height), transform=fig.transFigure)


def plot_clusters(result: dict[str, Any], compared: dict[str, Any] | None = None) -> bytes:
    """PNG bytes: positions relative to the mean of all stops (µm), one colour per direction, the direction
    means, the enclosing and goal circles, and the report's header (job, date, mark, calibration,
    compensations, verdict, goals, angle convention) beside them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    marks = result["marks"]
    xy = np.array([m["abs_xyz"][:2] for m in marks])
    ks = np.array([m.get("k", 0) for m in marks])
    headings = np.array([m["heading_deg"] for m in marks])
    metrics = result.get("metrics") or {}
    centre = xy.mean(axis=0)
    rel = (xy - centre) * 1000.0
    fit = metrics.get("fit") or {}
    fit_xy = None if fit.get("M") is None else (np.asarray(fit["M"][:2], float) - centre) * 1000.0
    fig = plt.figure(figsize=(14, 8), dpi=100)
    ax = fig.add_axes((0.06, 0.07, 0.48, 0.83))
    _clusters(ax, rel, ks, headings, [c["name"] for c in metrics.get("clusters") or []])
    c, lim = _references(ax, rel, fit_xy, metrics.get("enclosing_diameter_mm"))
    lim = max(lim, 10.0)  # both circles in view; the origin is in the enclosing one (the mean of its points)
    ax.set_aspect("equal")
    ax.set_xlim(c[0] - lim, c[0] + lim)
    ax.set_ylim(c[1] - lim, c[1] + lim)
    ax.set_xlabel(f"ACS x − {centre[0]:.4f} mm  [µm]")
    ax.set_ylabel(f"ACS y − {centre[1]:.4f} mm  [µm]")
    ax.set_title(f"Mark measured from {len(set(ks.tolist()))} directions, {len(marks)} stops, relative to "
                 f"the mean of all stops\nACS ({centre[0]:.4f}, {centre[1]:.4f}) mm", fontsize=10)
    ax.grid(alpha=0.3)
    _stack(fig, fig.text(0.575, 0.97, _header_text(result, compared), va="top", ha="left", fontsize=7,
                         family="monospace"), ax.legend(fontsize=7, loc="upper left", borderaxespad=0.0))
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()
