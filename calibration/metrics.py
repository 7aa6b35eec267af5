"""Repeatability metrics of the 8-direction experiment, in the paper's table format.

Per approach direction: mean position, max and mean distance from the mean, the exact
minimum enclosing circle radius and the approach-angle range; the same for all points
("All" row); the mean L2 distance between cluster means in both readings (mean over
pairs, mean distance to their centroid); and the least-squares fit of the cluster
means ``M_k = M + R(ψ_k)·b`` giving the mark M and the robot-frame bias b
(the 8 directions as a multi-step error separation: Evans, Hocken and Estler 1996).

The enclosing circle is Welzl's algorithm in float64 on coordinates centred and
scaled to µm: ``cv2.minEnclosingCircle`` works in float32 and pads the radius by
about 1e-4 input units (measured).
"""
from __future__ import annotations

import io
import itertools
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

#: direction names by nominal heading (deg), as in the paper's table (0° = "up")
DIRECTION_NAMES = {0: "up", 45: "upleft", 90: "left", 135: "downleft", 180: "down",
                   -135: "downright", -90: "right", -45: "upright"}


def _circle2(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    c = (a + b) / 2
    return c, float(np.linalg.norm(a - c))


def _circle3(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, float]:
    """Circumcircle; for (nearly) collinear points the circle over the farthest pair."""
    bx, by = b - a
    cx, cy = c - a
    d = 2 * (bx * cy - by * cx)
    scale = max(bx * bx + by * by, cx * cx + cy * cy, 1e-300)
    if abs(d) < 1e-12 * scale:
        return max((_circle2(p, q) for p, q in ((a, b), (a, c), (b, c))), key=lambda x: x[1])
    ux = (cy * (bx * bx + by * by) - by * (cx * cx + cy * cy)) / d
    uy = (bx * (cx * cx + cy * cy) - cx * (bx * bx + by * by)) / d
    centre = a + np.array([ux, uy])
    return centre, float(np.hypot(ux, uy))


def min_enclosing_circle(points: Any, seed: int = 0) -> tuple[np.ndarray, float]:
    """Exact smallest circle containing all 2D ``points`` (N, 2): ``(centre, radius)``, same units."""
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 2 or len(P) == 0:
        raise ValueError(f"min_enclosing_circle: expected an (N, 2) array with N >= 1, got shape {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError("min_enclosing_circle: points contain non-finite values")
    origin = P.mean(axis=0)
    span = float(np.abs(P - origin).max()) or 1.0
    Q = (P - origin) / span  # well conditioned, whatever the input units
    Q = Q[np.random.default_rng(seed).permutation(len(Q))]  # expected linear time
    eps = 1e-12

    def outside(p: np.ndarray, c: np.ndarray, r: float) -> bool:
        """Is ``p`` outside the circle (c, r), with a small tolerance?"""
        return float(np.linalg.norm(p - c)) > r + eps

    c, r = Q[0].copy(), 0.0
    for i in range(1, len(Q)):
        if not outside(Q[i], c, r):
            continue
        c, r = Q[i].copy(), 0.0
        for j in range(i):
            if not outside(Q[j], c, r):
                continue
            c, r = _circle2(Q[i], Q[j])
            for k in range(j):
                if outside(Q[k], c, r):
                    c, r = _circle3(Q[i], Q[j], Q[k])
    return origin + c * span, r * span


def wrap_deg(a: Any) -> Any:
    """Angle(s) wrapped to [−180, 180)."""
    return (np.asarray(a, dtype=float) + 180.0) % 360.0 - 180.0


def direction_name(nominal_deg: float) -> str:
    """Paper-style name for a heading that is a multiple of 45°, else e.g. '30deg'."""
    k = int(round(float(wrap_deg(nominal_deg))))
    k = 180 if k == -180 else k
    return DIRECTION_NAMES.get(k, f"{k}deg")


@dataclass
class ClusterStats:
    """One row of the table: a cluster of measurements (or all of them)."""

    name: str
    n: int
    mean: list[float]  # ACS x, y, mm
    max_from_mean_mm: float
    mean_from_mean_mm: float
    radius_mm: float  # minimum enclosing circle
    angle_range_deg: list[float] | None  # [min, max] approach heading


def mean_heading_deg(h: np.ndarray) -> float:
    """Circular mean: headings either side of ±180° average to ±180°, not to 0."""
    return float(np.degrees(np.arctan2(np.sin(np.radians(h)).mean(), np.cos(np.radians(h)).mean())))


def cluster_stats(name: str, xy: np.ndarray, headings: np.ndarray | None) -> ClusterStats:
    """Table row for one cluster: mean, distances from it, enclosing radius, heading range."""
    m = xy.mean(axis=0)
    d = np.linalg.norm(xy - m, axis=1)
    _, r = min_enclosing_circle(xy)
    rng = None
    if headings is not None:
        ref = mean_heading_deg(headings)
        dev = wrap_deg(headings - ref)
        rng = [ref + float(dev.min()), ref + float(dev.max())]
    return ClusterStats(name, len(xy), m.tolist(), float(d.max()), float(d.mean()), r, rng)


@dataclass
class BiasFit:
    """Least-squares ``M_k = M + R(ψ_k)·b`` over the cluster means."""

    M: list[float]  # the mark, ACS xy, mm
    b: list[float]  # robot-frame bias, RCS xy, mm
    b_norm_mm: float
    rms_mm: float  # residual RMS of the cluster means


def bias_design(headings_deg: Any) -> np.ndarray:
    """The model M + R(ψ_k)·b as a design matrix: rows x, y per point; columns M_x, M_y, b_x, b_y."""
    psi = np.radians(np.asarray(headings_deg, dtype=float).reshape(-1))
    c, s = np.cos(psi), np.sin(psi)
    A = np.zeros((2 * len(psi), 4))
    A[0::2, 0], A[1::2, 1] = 1, 1
    A[0::2, 2], A[0::2, 3] = c, -s
    A[1::2, 2], A[1::2, 3] = s, c
    return A


def fit_bias(means: np.ndarray, headings_deg: np.ndarray) -> BiasFit:
    """Fit the true mark M (ACS-fixed) and robot-frame bias b to cluster means at headings ψ_k."""
    means = np.asarray(means, dtype=float)
    psi = np.radians(np.asarray(headings_deg, dtype=float))
    if len(means) < 3:
        raise ValueError(f"fit_bias: need at least 3 directions to separate M and b, got {len(means)}")
    A = bias_design(headings_deg)
    if np.linalg.cond(A) > 1e6:
        raise ValueError(f"fit_bias: headings {np.degrees(psi).round(1).tolist()} do not separate M from b")
    x, *_ = np.linalg.lstsq(A, means.reshape(-1), rcond=None)
    res = means.reshape(-1) - A @ x
    return BiasFit(x[:2].tolist(), x[2:].tolist(), float(np.hypot(*x[2:])),
                   float(np.sqrt(np.mean(res.reshape(-1, 2) ** 2 @ np.ones(2)))))


@dataclass
class ExperimentMetrics:
    """The paper's table plus the between-cluster figures and the bias fit."""

    clusters: list[ClusterStats]
    all: ClusterStats
    pairwise_mean_mm: float  # mean L2 distance over all pairs of cluster means
    centroid_mean_mm: float  # mean distance of the cluster means to their centroid
    fit: BiasFit | None
    extra: dict[str, Any] = field(default_factory=dict)
    #: the robot-frame bias already subtracted at every stop (the calibration's b), or None: the fitted b is
    #: then what is left of the bias after it, not the bias itself, and the table says so (not in to_dict:
    #: the result has it as compensation.robot_bias_mm, and recompute compares metrics key by key)
    applied_b: list[float] | None = None
    #: a bias applied at some stops only: said under the table (the fit mixes both), not in to_dict either
    partly_applied: str = ""

    @property
    def enclosing_diameter_mm(self) -> float:
        """Minimum enclosing circle diameter of all points (the paper's 0.747 mm)."""
        return 2 * self.all.radius_mm

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {"clusters": [asdict(c) for c in self.clusters], "all": asdict(self.all),
                "enclosing_diameter_mm": self.enclosing_diameter_mm,
                "pairwise_mean_mm": self.pairwise_mean_mm, "centroid_mean_mm": self.centroid_mean_mm,
                "fit": None if self.fit is None else asdict(self.fit), **self.extra}

    def rows(self) -> list[list[str]]:
        """Table rows (header first), numbers formatted as in the paper."""
        out = [["Direction", "Mean X [mm]", "Mean Y [mm]", "Max from Mean [mm]", "Mean from Mean [mm]",
                "Cluster Radius [mm]", "Approach Angle Range [deg]"]]
        for c in [*self.clusters, self.all]:
            ang = "" if c.angle_range_deg is None or c is self.all else \
                f"[{c.angle_range_deg[0]:.2f}, {c.angle_range_deg[1]:.2f}]"
            out.append([c.name, f"{c.mean[0]:.3f}", f"{c.mean[1]:.3f}", f"{c.max_from_mean_mm:.3f}",
                        f"{c.mean_from_mean_mm:.3f}", f"{c.radius_mm:.3f}", ang])
        return out

    def summary(self) -> list[tuple[str, str]]:
        """The figures below the table, as (label, formatted value)."""
        s = [("Enclosing diameter, all points [mm]", f"{self.enclosing_diameter_mm:.3f}"),
             ("Mean L2 distance between cluster means, over pairs [mm]", f"{self.pairwise_mean_mm:.3f}"),
             ("Mean L2 distance of cluster means to their centroid [mm]", f"{self.centroid_mean_mm:.3f}")]
        if self.applied_b is not None:
            s += [("Robot-frame bias b applied at every stop, the calibration's (x, y) [mm]",
                   f"{self.applied_b[0]:.4f}, {self.applied_b[1]:.4f}")]
        if self.partly_applied:
            s += [("Robot-frame bias b applied at", self.partly_applied)]
        if self.fit is not None:
            # with a bias applied, the fit sees only what is left of it: named so, never as "the" bias
            b = "b left after the applied b" if self.applied_b is not None else "b"
            s += [("Fitted mark M (x, y) [mm]", f"{self.fit.M[0]:.3f}, {self.fit.M[1]:.3f}"),
                  (f"Robot-frame bias {b}, fitted to these marks (x, y) [mm]",
                   f"{self.fit.b[0]:.4f}, {self.fit.b[1]:.4f}"),
                  (f"|{b}| [mm]", f"{self.fit.b_norm_mm:.4f}"),
                  ("Fit residual RMS [mm]", f"{self.fit.rms_mm:.4f}")]
        s += [(k, f"{v:.4f}" if isinstance(v, float) else str(v)) for k, v in self.extra.items()]
        return s

    def to_markdown(self) -> str:
        """The paper's table as Markdown, with the summary lines under it."""
        rows = self.rows()
        lines = ["| " + " | ".join(rows[0]) + " |", "|" + "|".join(["---"] + ["---:"] * 6) + "|"]
        for row in rows[1:]:
            name = f"**{row[0]}**" if row[0] == "All" else row[0]
            lines.append("| " + " | ".join([name, *row[1:]]) + " |")
        lines.append("")
        lines += [f"*{k}*: {v}  " for k, v in self.summary()]
        return "\n".join(lines) + "\n"

    #: the columns of :meth:`to_csv` (docs/datasets.md, "Experiment report")
    CSV_COLUMNS = ("direction", "n", "mean_x_mm", "mean_y_mm", "max_from_mean_mm", "mean_from_mean_mm",
                   "radius_mm", "heading_min_deg", "heading_max_deg")

    def to_csv(self) -> str:
        """The table as one tidy CSV: a header row, a row per direction and the ``All`` row, one number a
        cell in full precision (the All row has no heading range: empty cells)."""
        import csv

        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(self.CSV_COLUMNS)
        for c in [*self.clusters, self.all]:
            rng = c.angle_range_deg if c is not self.all and c.angle_range_deg is not None else ["", ""]
            w.writerow([c.name, c.n, *(repr(float(v)) for v in (*c.mean[:2], c.max_from_mean_mm,
                                                                 c.mean_from_mean_mm, c.radius_mm)),
                        *(v if v == "" else repr(float(v)) for v in rng)])
        return buf.getvalue()


def experiment_metrics(points: Any, headings_deg: Any, groups: Any = None) -> ExperimentMetrics:
    """Metrics of measured mark positions (N, 2 or 3; ACS mm) taken at approach headings (N,) in degrees.

    Points are grouped by ``groups`` labels if given, else by the heading rounded to the
    nearest multiple of 45°; clusters are named as in the paper (given groups keep
    their labels unless their mean headings are distinct multiples of 45°).
    """
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] not in (2, 3) or len(P) < 1:
        raise ValueError(f"experiment_metrics: points must be (N, 2) or (N, 3), got shape {P.shape}")
    xy = P[:, :2]
    h = np.asarray(headings_deg, dtype=float).reshape(-1)
    if len(h) != len(xy) or not np.all(np.isfinite(h)) or not np.all(np.isfinite(xy)):
        raise ValueError(f"experiment_metrics: need {len(xy)} finite headings and points, "
                         f"got {len(h)} headings")
    if groups is None:
        nominal = wrap_deg(np.round(h / 45.0) * 45.0)
        nominal[nominal == -180.0] = 180.0
        labels = [direction_name(a) for a in nominal]
    else:
        labels = [str(g) for g in groups]
        if len(labels) != len(xy):
            raise ValueError(f"experiment_metrics: {len(labels)} group labels for {len(xy)} points")
    order = list(dict.fromkeys(labels))
    members = [np.array([i for i, g in enumerate(labels) if g == name]) for name in order]
    mean_h = [mean_heading_deg(h[idx]) for idx in members]
    if groups is not None:
        # given groups (e.g. direction indices) get the paper's names when their mean
        # headings are distinct multiples of 45°; otherwise the labels are kept
        near = [abs(float(wrap_deg(a - 45.0 * round(a / 45.0)))) < 10.0 for a in mean_h]
        named = [direction_name(45.0 * round(a / 45.0)) for a in mean_h]
        if all(near) and len(set(named)) == len(named):
            order = named
    clusters = [cluster_stats(name, xy[idx], h[idx]) for name, idx in zip(order, members)]
    means = [xy[idx].mean(axis=0) for idx in members]
    allc = cluster_stats("All", xy, None)
    means_a = np.array(means)
    pairs = [np.linalg.norm(a - b) for a, b in itertools.combinations(means_a, 2)]
    pairwise = float(np.mean(pairs)) if pairs else 0.0
    centroid = float(np.mean(np.linalg.norm(means_a - means_a.mean(axis=0), axis=1)))
    fit = fit_bias(means_a, np.array(mean_h)) if len(means_a) >= 3 else None
    return ExperimentMetrics(clusters, allc, pairwise, centroid, fit)
