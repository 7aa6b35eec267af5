"""The tables of bench/accuracy_shapes.py (markdown, for docs/accuracy.md "Unmodelled path shapes").

Goals (issue #33, Acceptance): per case p95 |e|/σ ≤ 1.73 or the verdict ``warn``; a shape changed
after learning: ``warn`` on ≥ 90 % of the seeds where the applied weight is > 10 % worse than the chord,
and never > 10 % worse with ``ok``; the stored b/w never > 10 % worse (enclosing or absolute RMS) than
the better of the chord with its own b and the joint fit.
"""
from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np

#: |e|/σ's p95 of an honest isotropic 2-D Gaussian σ (χ² with 2 degrees of freedom)
HONEST_P95 = 1.731
#: "worse" means worse by more than this fraction
WORSE = 0.10
#: the share of worse-than-chord seeds that must warn
WARN_SHARE = 0.90
#: the figures compared for "worse"
FIGURES = ("enclosing_mm", "abs_rms_mm")


def _mp(v: list[float]) -> str:
    return f"{np.median(v):.3f} / {np.percentile(v, 95):.3f}" if v else "–"


def _key(r: dict[str, Any]) -> tuple[int, str, str, str]:
    return r["seed"], r.get("world", ""), r["learned_on"], r["shape"]


def _label(world: str, learned: str, shape: str) -> str:
    """A case's name: the shape (learned on another: both), after the envelope world's name if any."""
    label = shape if learned == shape else f"{learned} → {shape}"
    return f"{world}: {label}" if world else label


def _uncovered(rows: list[dict[str, Any]]) -> tuple[int, int, int]:
    """(cases with p95 |e|/σ above 1.73, of them with warn, of them with ok: the misses)."""
    bad = [r for r in rows if r["p95_ratio"] > HONEST_P95]
    warned = sum(r["verdict"] != "ok" for r in bad)
    return len(bad), warned, len(bad) - warned


def coverage_table(rows: list[dict[str, Any]]) -> str:
    """Per shape pair and compensation: |e|/σ, the paper's figures and the verdicts."""
    out = ["| learned on → scored on | comp. | cases | p95 \\|e\\|/σ median / max | > 1.73 | of them warn "
           "| > 1.73 with ok (goal 0) | enclosing | abs. RMS | pairwise | warn |",
           "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    pairs = sorted({(r.get("world", ""), r["learned_on"], r["shape"]) for r in rows},
                   key=lambda p: (p[0], p[1] != p[2], p))
    for world, learned, shape in pairs:
        for comp in ("default", "chord"):
            rs = [r for r in rows if _key(r)[1:] + (r["comp"],) == (world, learned, shape, comp)]
            if not rs:
                continue
            ratio = [r["p95_ratio"] for r in rs]
            n_bad, warned, missed = _uncovered(rs)
            out.append(f"| {_label(world, learned, shape)} | {comp} | {len(rs)} | "
                       f"{np.median(ratio):.2f} / {max(ratio):.2f} | "
                       f"{n_bad} | "
                       f"{warned} | {missed}{' **missed**' if missed else ''} | "
                       f"{_mp([r['enclosing_mm'] for r in rs])} | {_mp([r['abs_rms_mm'] for r in rs])} | "
                       f"{_mp([r['pairwise_mm'] for r in rs])} | {sum(r['verdict'] != 'ok' for r in rs)} |")
    return "\n".join(out)


def _pairs(rows: list[dict[str, Any]]) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    chord = {_key(r): r for r in rows if r["comp"] == "chord"}
    return [(r, chord[_key(r)]) for r in rows if r["comp"] == "default" and _key(r) in chord]


def _worse(a: dict[str, Any], b: dict[str, Any]) -> float:
    """How much worse ``a`` is than ``b`` on the worse of the compared figures (fraction)."""
    return max(a[k] / b[k] - 1.0 for k in FIGURES)


def changed_table(rows: list[dict[str, Any]]) -> str:
    """A shape changed after learning: the default's weight worse than the chord, and whether it warned."""
    out = ["| learned on → scored on | seeds | default > 10 % worse than the chord "
           "| of them warn (goal ≥ 90 %) | > 10 % worse with ok (goal 0) | worst excess |",
           "|---|---:|---:|---:|---:|---:|"]
    tot = [0, 0, 0]
    changed = {(r["learned_on"], r["shape"]) for r in rows if r["learned_on"] != r["shape"]}
    for learned, shape in sorted(changed):
        ps = [(d, c) for d, c in _pairs(rows) if (d["learned_on"], d["shape"]) == (learned, shape)]
        worse = [(d, c) for d, c in ps if _worse(d, c) > WORSE]
        warned = sum(d["verdict"] != "ok" for d, _ in worse)
        excess = max((_worse(d, c) for d, c in ps), default=math.nan)
        tot = [tot[0] + len(ps), tot[1] + len(worse), tot[2] + warned]
        out.append(f"| {learned} → {shape} | {len(ps)} | {len(worse)} | "
                   f"{warned}{_share(warned, len(worse))} | "
                   f"{len(worse) - warned}{' **missed**' if len(worse) > warned else ''} | {excess:+.0%} |")
    out.append(f"| all | {tot[0]} | {tot[1]} | {tot[2]}{_share(tot[2], tot[1])} | {tot[1] - tot[2]}"
               f"{' **missed**' if tot[1] > tot[2] else ''} | |")
    return "\n".join(out)


def _share(k: int, n: int) -> str:
    if not n:
        return ""
    return f" ({k / n:.0%}{'' if k / n >= WARN_SHARE else ' **missed**'})"


def cv_table(rows: list[dict[str, Any]], before: list[dict[str, Any]] | None) -> str:
    """The stored b/w against the better of the chord with its own b and the joint fit (the default as it
    was ``before`` a change, else this run's default), on the cases learned and scored on one shape."""
    own = [r for r in rows if r["comp"] == "joint"]  # a --joint run: its own joint fit
    joint = {_key(r): r for r in (own or before or rows) if r["comp"] == ("joint" if own else "default")}
    out = ["| cases | stored b/w > 10 % worse than the better of chord-own-b and joint fit (goal 0) "
           "| on enclosing | on abs. RMS | worst excess |", "|---:|---:|---:|---:|---:|"]
    n = worse = enc = rms = 0
    excess = -math.inf
    for d, c in _pairs(rows):
        j = joint.get(_key(d))
        if j is None or d["learned_on"] != d["shape"]:  # learned and scored on one robot
            continue
        best = {k: min(c[k], j[k]) for k in FIGURES}
        e = {k: d[k] / best[k] - 1.0 for k in FIGURES}
        n += 1
        enc, rms = enc + (e["enclosing_mm"] > WORSE), rms + (e["abs_rms_mm"] > WORSE)
        worse += max(e.values()) > WORSE
        excess = max(excess, max(e.values()))
    out.append(f"| {n} | {worse}{' **missed**' if worse else ''} | {enc} | {rms} | {excess:+.0%} |")
    return "\n".join(out)


def weight_table(rows: list[dict[str, Any]]) -> str:
    """The applied weight against the scored experiment's own (same shape): z with both σs."""
    out = ["| shape | cases | rms z | \\|z\\| > 2 | \\|z\\| > 3 |", "|---|---:|---:|---:|---:|"]
    for world, shape in sorted({(r.get("world", ""), r["shape"]) for r in rows}):
        zs = [(r["own_weight"] - r["weight_fit"]) / math.hypot(r["weight_sigma"], r["own_sigma"])
              for r in rows if r["comp"] == "default" and r["shape"] == r["learned_on"] == shape
              and r.get("world", "") == world
              and None not in (r["own_weight"], r["weight_fit"], r["weight_sigma"], r["own_sigma"])
              and math.isfinite(math.hypot(r["weight_sigma"], r["own_sigma"]))]
        if zs:
            z = np.array(zs)
            out.append(f"| {_label(world, shape, shape)} | {len(z)} | {np.sqrt(np.mean(z ** 2)):.2f} | "
                       f"{int(np.sum(abs(z) > 2))} | "
                       f"{int(np.sum(abs(z) > 3))} |")
    return "\n".join(out)


def reasons(rows: list[dict[str, Any]]) -> str:
    """The warnings' messages (each message's text up to its first figure), most frequent first."""
    c: Counter[str] = Counter()
    for r in rows:
        if r["verdict"] != "ok":
            for m in r["messages"]:
                # the weight's own report, and a σ factor within the checks, are no reason
                if not m.startswith("heading_fit: ") and "within the checks" not in m:
                    c[m.split("(")[0].split(":")[0][:90]] += 1
    return "\n".join(f"- {n} × {m}" for m, n in c.most_common(8)) or "- none"


def tables(rows: list[dict[str, Any]], before: list[dict[str, Any]] | None = None) -> str:
    """Every table of the section, with the run's size."""
    seeds = sorted({r["seed"] for r in rows})
    secs = [r["seconds_per_seed"] for r in rows]
    head = (f"{len(seeds)} seeds ({seeds[0]}–{seeds[-1]}), {len(rows)} cases; "
            f"{np.median(secs):.0f} s per seed (median, one process)") if rows else "no rows"
    changed = ["Shape changed after learning (default against the chord, same seed):", changed_table(rows)]
    return "\n\n".join([head, "Coverage, the paper's figures (median / p95, mm) and verdicts:",
                        coverage_table(rows),
                        *(changed if any(r["learned_on"] != r["shape"] for r in rows) else []),
                        "Stored b/w against the better of chord-own-b and joint fit:", cv_table(rows, before),
                        "The applied weight against the scored experiment's own:", weight_table(rows),
                        "Why the verdicts warned:", reasons(rows)])


__all__ = ["changed_table", "coverage_table", "cv_table", "reasons", "tables", "weight_table"]
