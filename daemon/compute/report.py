"""The experiment plot: every measured mark position per approach direction, like the paper's figure."""
from __future__ import annotations

import io
from typing import Any

import numpy as np


def plot_clusters(result: dict[str, Any]) -> bytes:
    """PNG bytes: positions relative to the overall mean (µm), one colour per direction, means and circle."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from calibration.metrics import direction_name, min_enclosing_circle

    marks = result["marks"]
    xy = np.array([m["abs_xyz"][:2] for m in marks])
    ks = np.array([m.get("k", 0) for m in marks])
    headings = np.array([m["heading_deg"] for m in marks])
    centre = xy.mean(axis=0)
    rel = (xy - centre) * 1000.0
    fig, ax = plt.subplots(figsize=(7, 6.5), dpi=110)
    cmap = plt.get_cmap("tab10")
    for i, k in enumerate(sorted(set(ks.tolist()))):
        sel = ks == k
        h = np.radians(headings[sel])
        mean_h = float(np.degrees(np.arctan2(np.sin(h).mean(), np.cos(h).mean())))  # circular: ±180° wraps
        name = direction_name(float(np.round(mean_h / 45.0) * 45.0))
        ax.scatter(rel[sel, 0], rel[sel, 1], s=22, color=cmap(i % 10), label=f"{name} ({mean_h:.0f}°)")
        m = rel[sel].mean(axis=0)
        ax.scatter([m[0]], [m[1]], marker="x", s=80, color=cmap(i % 10))
    c, r = min_enclosing_circle(rel)
    ax.add_patch(plt.Circle((float(c[0]), float(c[1])), r, fill=False, ls="--", color="grey",
                            label=f"enclosing circle, d = {2 * r:.0f} µm"))
    ax.set_aspect("equal")
    lim = max(r * 1.25, 10.0)
    ax.set_xlim(c[0] - lim, c[0] + lim)
    ax.set_ylim(c[1] - lim, c[1] + lim)
    ax.set_xlabel("ACS x − mean [µm]")
    ax.set_ylabel("ACS y − mean [µm]")
    fit = result["metrics"].get("fit") or {}
    title = f"Mark measured from {len(set(ks.tolist()))} directions, {len(marks)} stops"
    if fit.get("b_norm_mm") is not None:
        title += f"\nfitted robot-frame bias |b| = {fit['b_norm_mm'] * 1000:.1f} µm"
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()
