"""Figures against goals, and repeated reasons, worded one way wherever they are printed.

A goal printed without its verdict hides a miss from whoever reads quickly: every
figure shown next to a goal goes through :func:`goal_text`, which ends in ``met`` or
``MISSED`` (a value that is not a number cannot meet a goal: MISSED). A reason that
holds for many stops or photographs is printed once with its count (:func:`counted`),
so that the line stays readable and the count is not lost.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Iterable

#: the comparison a goal states, and how it is printed
_OPS = {"<": (lambda v, g: v < g), "<=": (lambda v, g: v <= g), ">": (lambda v, g: v > g),
        ">=": (lambda v, g: v >= g)}
_SHOWN = {"<": "<", "<=": "≤", ">": ">", ">=": "≥"}


@dataclass(frozen=True)
class Goal:
    """A figure's goal: ``value <op> limit`` (``op`` one of ``< <= > >=``), in ``unit``."""

    op: str
    limit: float
    unit: str = ""

    def __post_init__(self) -> None:
        if self.op not in _OPS:
            raise ValueError(f"Goal: op {self.op!r} is not one of {', '.join(_OPS)}")

    def met(self, value: float | None) -> bool:
        """Whether ``value`` meets the goal (NaN or None never does)."""
        return value is not None and math.isfinite(value) and bool(_OPS[self.op](value, self.limit))

    def text(self) -> str:
        """``goal ≤ 0.25 mm``."""
        return f"goal {_SHOWN[self.op]} {self.limit:g}{_unit(self.unit)}"


def _unit(unit: str) -> str:
    return "" if not unit else unit if unit in ("°", "%") else " " + unit


def verdict(ok: bool) -> str:
    """The one spelling of a verdict: ``met`` or ``MISSED``."""
    return "met" if ok else "MISSED"


def goal_text(value: float | None, goal: Goal, fmt: str = ".3f", label: str = "") -> str:
    """``label value unit (goal …): met`` or ``…: MISSED``; the value in the goal's unit."""
    shown = "nan" if value is None or not math.isfinite(value) else format(value, fmt)
    head = f"{label} " if label else ""
    return f"{head}{shown}{_unit(goal.unit)} ({goal.text()}): {verdict(goal.met(value))}"


def goal_cell(value: float, goal: Goal) -> str:
    """A table's goal column: ``≤ 0.25 met`` / ``≤ 0.25 **MISSED**`` (the unit is in the row's label)."""
    ok = goal.met(value)
    return f"{_SHOWN[goal.op]} {goal.limit:g} {verdict(ok) if ok else '**' + verdict(ok) + '**'}"


_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?")


def _span(numbers: list[str]) -> str:
    """One number slot over several reasons: the value, or ``min–max`` as the reasons printed them."""
    if len(set(numbers)) == 1:
        return numbers[0]
    values = [float(n) for n in numbers]
    return f"{numbers[values.index(min(values))]}–{numbers[values.index(max(values))]}"


def counted(reasons: Iterable[str]) -> list[str]:
    """Reasons once each, in first-seen order, ``×n`` after one that came n > 1 times.

    Reasons that differ only in their numbers (``… by 0.0239° …``, ``… by 0.0280° …``) are one
    reason with each differing number shown as its range (``by 0.0239–0.0280°``).
    """
    groups: dict[tuple[str, int], list[list[str]]] = {}
    for r in reasons:
        numbers = _NUMBER.findall(r)
        groups.setdefault((_NUMBER.sub("#", r), len(numbers)), []).append(numbers)
    out = []
    for (template, _), found in groups.items():
        parts = template.split("#")
        slots = [_span([n[i] for n in found]) for i in range(len(parts) - 1)]
        text = parts[0] + "".join(s + p for s, p in zip(slots, parts[1:]))
        out.append(text if len(found) == 1 else f"{text} ×{len(found)}")
    return out


def counted_from(counts: dict[str, int]) -> list[str]:
    """:func:`counted` of reasons stored with their counts (``{reason: n}``)."""
    return counted(r for r, n in counts.items() for _ in range(int(n)))


#: the product's accuracy goals for the 8-direction experiment with the default compensation
#: (docs/accuracy.md, "The goals at p95"), mm, by metric key; the absolute RMS needs the true
#: mark: only a simulation scores it
ACCURACY_GOALS_MM = {"enclosing_mm": 0.25, "pairwise_mm": 0.07, "abs_rms_mm": 0.10}
#: the goals an experiment can judge from its own marks: (label, key in its result's ``metrics``, goal)
EXPERIMENT_GOALS = (("enclosing diameter", "enclosing_diameter_mm",
                     Goal("<=", ACCURACY_GOALS_MM["enclosing_mm"], "mm")),
                    ("mean pairwise distance of cluster means", "pairwise_mean_mm",
                     Goal("<=", ACCURACY_GOALS_MM["pairwise_mm"], "mm")))


def experiment_goal_lines(metrics: dict[str, object] | None) -> list[str]:
    """An experiment's own figures against :data:`EXPERIMENT_GOALS`, each ``…: met`` or ``…: MISSED``
    (none without metrics; a figure the metrics lack is not a number: MISSED). One run is judged
    against the goals docs/accuracy.md states at p95 over runs: a run that meets them is one
    sample of that p95, not the p95 itself."""
    if not metrics:
        return []
    out = []
    for label, key, goal in EXPERIMENT_GOALS:
        value = metrics.get(key)
        out.append(goal_text(float(value) if isinstance(value, (int, float)) else None, goal, label=label))
    return out


#: why the enclosing diameter can grow when the other figures shrink (docs/accuracy.md, "Through ritad and
#: the worker"): tilt, bias and mount move a direction's marks together; the bends scatter them within one
WITHIN = ("tilt, bias and mount move each direction's marks together (they close the gaps between "
          "directions); the enclosing diameter also holds the scatter within a direction from the bent "
          "drives, which only heading_fit corrects")


def not_applied(comp: dict[str, Any]) -> list[str]:
    """Each requested compensation some stops skipped (a result's ``compensation`` summary): at how many
    stops it applied, why not (counted)."""
    stops, out = comp.get("stops", 0), []
    for name, why in (comp.get("skipped") or {}).items():
        counts = (comp.get("skipped_stops") or {}).get(name)
        reasons = counted_from(counts) if counts else counted(why)
        out.append(f"{name} applied at {(comp.get('applied') or {}).get(name, 0)} of {stops} stops: "
                   f"{'; '.join(reasons)}")
    return out


def worse_lines(label: str, without: float, with_: float, comp: dict[str, Any], enclosing: bool = False,
                left_out: dict[str, float] | None = None) -> list[str]:
    """Nothing when the compensations did not make a figure (mm, shown to 0.001) worse; else a ``WORSE`` line
    naming the compensations that made it worse when ``left_out`` (the figure with each applied one left out
    alone) shows them; else the possible reasons: the bends left within a direction (``enclosing``: the
    enclosing diameter), each compensation some stops skipped, or that the run does not show why. Lines
    under another are indented ``  - `` per level."""
    if round(with_, 3) <= round(without, 3):  # worse as printed: what the reader sees
        return []
    head = (f"WORSE with the compensations: {label} {without:.3f} → {with_:.3f} mm "
            f"(+{with_ - without:.3f} mm)")
    lines, culprits = [], []
    if left_out:
        culprits = [n for n, v in left_out.items() if round(v, 3) < round(with_, 3)]
        head += f"; {' and '.join(culprits)} made it worse" if culprits else "; no one compensation alone did"
        lines.append("each left out alone: " + ", ".join(f"without {n} {v:.3f} mm"
                                                          for n, v in left_out.items()))
    if culprits:  # shown by the data: no guessing
        return [head] + [f"  - {w}" for w in lines]
    bends_left = (comp.get("applied") or {}).get("heading_fit", 0) < comp.get("stops", 0)
    why = [WITHIN] if enclosing and bends_left else []
    why += not_applied(comp) or ["every requested compensation was applied at every stop: this run does "
                                 "not show why"]
    return [head] + [f"  - {w}" for w in lines + ["possible reasons:"]] + [f"    - {w}" for w in why]
