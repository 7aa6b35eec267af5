"""Error budget on a realistic robot: profile × compensation, and each effect's share.

Rendering-free simulation protocol (fakes/accuracy.py: referencing on the plate with PnP on
projected corners + 0.05 px; with the bias compensation an 8 × 5 learning experiment over mark
M2 first; the scored 8 × 5 experiment over mark M1; marks + 0.05 px). Each figure is the median
/ p95 over seeds. Tables:

1. profile × compensation: the paper's two metrics, the absolute mark error against truth,
   rob_H_cam's error;
2. each error group switched off in turn, without and with every compensation;
3. absolute error against the mark's position in the image (marks spread over the field).

Writes the bar plot docs/img/accuracy-budget.png. ``--seeds`` (default 10), ``--quick`` (3
seeds, tables 1 and 3 only). ``--envelope`` instead: the product's default compensation on
``paper+imu`` with the goals judged at p95, one assumption moved at a time
(bench/accuracy_envelope.py), and how well the marks' stated σ covers their error.
docs/accuracy.md records the output.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.accuracy_envelope import envelope  # noqa: E402
from bench.accuracy_plot import budget_png  # noqa: E402
from bench.common import machine  # noqa: E402
from calibration.compensation import Compensation  # noqa: E402
from daemon.bus.procedure_params import COMPENSATION  # noqa: E402
from fakes.accuracy import GOALS_MM, PAPER_MM, Case, run, summarise  # noqa: E402
from fakes.errors import GROUPS  # noqa: E402
from fakes.world import World, WorldParams  # noqa: E402

ALL = Compensation.parse("all")
#: the product's default (daemon/bus/procedure_params.py)
DEFAULT = Compensation.parse(COMPENSATION.default)
#: table 1: the paper's method in each world, then the compensations added one at a time
CASES = (Case("ideal"), Case("paper"), Case("paper", Compensation.parse("heading_fit,bias")),
         Case("paper+imu"), Case("paper+imu", Compensation.parse("tilt")),
         Case("paper+imu", Compensation.parse("tilt,heading_fit")), Case("paper+imu", DEFAULT),
         Case("paper+imu", ALL))
HEAD = ("enclosing diameter", "pairwise cluster means", "abs. error RMS", "rob_H_cam t_xy",
        "rob_H_cam rotation [°]")


def seeds_of(n: int) -> list[int]:
    return [100 + s for s in range(n)]


def table(cases: tuple[Case, ...], seeds: list[int], cols: int = 5) -> tuple[str, dict[str, dict]]:
    """Markdown rows of median / p95 per case, and the summaries (for the plot)."""
    lines = ["| Case | " + " | ".join(HEAD[:cols]) + " |", "|---|" + "---:|" * cols]
    out = {}
    print("\n".join(lines), flush=True)
    for case in cases:
        s = summarise([run(case, seed) for seed in seeds])
        out[case.label] = s
        cells = [f"{m:.3f} / {p:.3f}" if k != "rotation_deg" else f"{m:.4f} / {p:.4f}"
                 for k, (m, p) in list(s.items())[:cols]]
        lines.append(f"| {case.label} | " + " | ".join(cells) + " |")
        print(lines[-1], flush=True)
    return "\n".join(lines), out


def budget(seeds: list[int]) -> str:
    """Each error group off in turn, paper (no compensation) and paper+imu (all compensations)."""
    rows = []
    for comp, profile in ((Compensation(), "paper"), (ALL, "paper+imu")):
        rows += [Case(profile, comp)] + [Case(profile, comp, (g,)) for g in GROUPS if not (g == "imu" and
                                                                                          profile == "paper")]
    return table(tuple(rows), seeds, cols=3)[0]


def by_image_position(seeds: list[int], n_bins: int = 4) -> str:
    """Absolute error against the mark's radius in the image (fraction of the half diagonal)."""
    lines = ["| Case | " + " | ".join(f"r {i / n_bins:.2f}–{(i + 1) / n_bins:.2f}" for i in range(n_bins))
             + " |", "|---|" + "---:|" * n_bins]
    p = WorldParams()
    K = World(p).camera_matrix((1000, 750))
    half_mm = 500.0 / K[0, 0] * p.cam_height_mm  # half the field's width on the floor
    print("\n".join(lines), flush=True)
    for comp, profile in ((Compensation(), "paper"), (ALL, "paper+imu")):
        case = Case(profile, comp, mark_window_mm=0.95 * half_mm)
        r, e = [], []
        for seed in seeds:
            res = run(case, seed)
            wh = np.array(res["size"], float)
            # the rest fell outside the image
            inside = np.all((res["uv"] >= 0) & (res["uv"] <= wh - 1), axis=1)
            r += list(np.linalg.norm(res["uv"][inside] - (wh - 1) / 2, axis=1)
                      / np.linalg.norm(wh / 2))
            e += list(res["err_mm"][inside])
        r_a, e_a = np.array(r), np.array(e)
        cells = []
        for i in range(n_bins):
            sel = (r_a >= i / n_bins) & (r_a < (i + 1) / n_bins)
            cells.append(f"{np.sqrt(np.mean(e_a[sel] ** 2)):.3f} ({sel.sum()})" if sel.any() else "–")
        lines.append(f"| {case.label}, marks within ±{0.95 * half_mm:.0f} mm | " + " | ".join(cells) + " |")
        print(lines[-1], flush=True)
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--quick", action="store_true", help="3 seeds, no per-effect table")
    ap.add_argument("--jobs", type=int, default=1, help="--envelope: cases run at once (processes)")
    ap.add_argument("--envelope", action="store_true", help="the default compensation's p95 goals and their "
                    "sensitivity envelope (use >= 20 seeds)")
    ap.add_argument("--png",
                    default=str(Path(__file__).resolve().parents[1] / "docs/img/accuracy-budget.png"))
    args = ap.parse_args()
    seeds = seeds_of(3 if args.quick else args.seeds)
    t0 = time.perf_counter()
    print(f"# Accuracy budget, {len(seeds)} seeds ({seeds[0]}…), median / p95, mm\n\n{machine()}\n")
    if args.envelope:
        print("## The default compensation at p95, and its sensitivity envelope (progress on stderr)\n")
        print(envelope(seeds, jobs=args.jobs))
        print(f"\n({time.perf_counter() - t0:.0f} s)")
        return
    print("## Profile × compensation\n")
    _, summary = table(CASES, seeds)
    budget_png(summary, GOALS_MM, PAPER_MM, Path(args.png))
    print(f"\n(plot: {args.png})\n")
    if not args.quick:
        print("## Each effect switched off\n")
        budget(seeds)
    print("\n## Absolute error against image position (r: radius / half diagonal; RMS mm, (stops))\n")
    by_image_position(seeds)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
