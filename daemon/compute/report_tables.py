"""An experiment's tidy CSV files: one table per file, one header row, one value per cell.

* ``report.csv`` — per direction, the paper's table (calibration/metrics.py ``to_csv``);
* ``report_metrics.csv`` — one row per figure: value, unit, and its goal with ``met``/``MISSED``;
* ``report_stops.csv`` — one row per stop: heading, the mark in ACS, its σ and σ's parts, and
  what each compensation did there.

Numbers are written in full (Python's shortest round-trip form), units are in the column names
or the ``unit`` column; docs/datasets.md ("Experiment report") lists every column.
"""
from __future__ import annotations

import csv
import io
from typing import Any, Iterable

import numpy as np
from calibration.compensation import names_known
from daemon.bus.figures import EXPERIMENT_GOALS, verdict
from daemon.compute.report_header import bias_applied

METRICS_COLUMNS = ["metric", "value", "unit", "goal_op", "goal_limit", "goal_verdict"]
#: σ's parts per stop (docs/datasets.md, "Units and conventions": ``sigma.parts_mm``)
SIGMA_PARTS = ("tracker", "pixel", "calibration", "tilt", "heading", "mount", "bias")
STOPS_FIXED = (["stop", "k", "direction", "heading_deg", "x_mm", "y_mm", "z_mm", "u_px", "v_px", "std_mm",
                "tracker_sigma_mm", "tracker_sigma_source", "tracker_distance_mm", "heading_sigma_rad",
                "heading_sigma_source"] + [f"std_{p}_mm" for p in SIGMA_PARTS])


def stops_columns() -> list[str]:
    """report_stops.csv's header: the fixed columns, then per compensation known here (built in, then
    registered: calibration/compensation.py ``names_known``) its state, skip reason and shift."""
    names = names_known()
    return (STOPS_FIXED + [c for n in names for c in (n, f"{n}_skipped_because")]
            + [f"shift_{n}_{a}_mm" for n in names for a in "xy"])


def _cell(v: Any) -> Any:
    """A cell: empty for None, a real number in full (numpy's too, never ``np.float64(…)``), else as is."""
    if v is None:
        return ""
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    return int(v) if isinstance(v, np.integer) else v


def _csv(rows: Iterable[list[Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerows([[_cell(v) for v in row] for row in rows])
    return buf.getvalue()


def _bias_rows(result: dict[str, Any]) -> list[list[Any]]:
    """The fitted bias under a name that says what it is: the whole bias, what is left after the
    calibration's b applied at every stop (that b beside it), or a mix of both (applied at some stops
    only); and the b fitted jointly with heading_fit's weight (what ``store_bias`` stores)."""
    fit, comp = (result.get("metrics") or {}).get("fit"), result.get("compensation") or {}
    if not fit:
        return []
    applied = bias_applied(comp)
    rows: list[list[Any]] = []
    if applied == "every":  # so the calibration's b is there
        held = comp["robot_bias_mm"]
        rows += [["bias_applied_x", float(held[0]), "mm"], ["bias_applied_y", float(held[1]), "mm"]]
    name = {"every": "bias_left_fitted", "some": "bias_fitted_mixed", "none": "bias_fitted"}[applied]
    rows += [[f"{name}_x", fit["b"][0], "mm"], [f"{name}_y", fit["b"][1], "mm"]]
    rows.append([f"{name}_norm", fit["b_norm_mm"], "mm"])
    joint = (result.get("heading_weight") or {}).get("b_mm")
    if joint is not None:
        rows += [["bias_fitted_with_weight_x", joint[0], "mm"], ["bias_fitted_with_weight_y", joint[1], "mm"]]
    return rows


def metrics_csv(result: dict[str, Any], plain: dict[str, Any] | None = None) -> str:
    """``report_metrics.csv``: each figure of the experiment a row; the goals' rows say met or MISSED;
    ``plain``: the metrics without compensation (their goal figures as ``…_without_compensation``)."""
    m = result.get("metrics") or {}
    goals = {key: goal for _, key, goal in EXPERIMENT_GOALS}
    allc, fit = m.get("all") or {}, m.get("fit") or {}
    rows: list[list[Any]] = [["stops", len(result.get("marks") or []), "count"],
                             ["directions", len(m.get("clusters") or []), "count"]]
    for key in ("enclosing_diameter_mm", "pairwise_mean_mm", "centroid_mean_mm"):
        rows.append([key.removesuffix("_mm"), m.get(key), "mm"])
    for key in (goals if plain else ()):  # the goals' figures without compensation, each judged too
        rows.append([f"{key.removesuffix('_mm')}_without_compensation", (plain or {}).get(key), "mm"])
    mean = allc.get("mean") or [None, None]
    rows += [["all_mean_x", mean[0], "mm"], ["all_mean_y", mean[1], "mm"],
             ["all_max_from_mean", allc.get("max_from_mean_mm"), "mm"],
             ["all_mean_from_mean", allc.get("mean_from_mean_mm"), "mm"]]
    if fit:
        rows += [["fitted_mark_x", fit["M"][0], "mm"], ["fitted_mark_y", fit["M"][1], "mm"]]
        rows += _bias_rows(result) + [["fit_residual_rms", fit["rms_mm"], "mm"]]
    out = [METRICS_COLUMNS]
    for name, value, unit in rows:
        goal = goals.get(f"{name.removesuffix('_without_compensation')}_mm")
        out.append([name, value, unit,
                    *(["", "", ""] if goal is None else [goal.op, goal.limit, verdict(goal.met(value))])])
    return _csv(out)


def _direction_names(result: dict[str, Any]) -> dict[Any, str]:
    """Each stop's ``k`` → its cluster's name (calibration/metrics.py names clusters in first-seen
    order)."""
    ks = list(dict.fromkeys(m.get("k", 0) for m in result.get("marks") or []))
    names = [c["name"] for c in (result.get("metrics") or {}).get("clusters") or []]
    return dict(zip(ks, names)) if len(names) == len(ks) else {}


def _comp_cells(rec: dict[str, Any] | None) -> list[Any]:
    """Per compensation: ``applied``, ``skipped`` (and why) or ``not requested``."""
    rec = rec or {}
    out: list[Any] = []
    for n in names_known():
        state = "applied" if n in rec.get("applied", []) else "skipped" if n in rec.get("requested", []) \
            else "not requested"
        out += [state, (rec.get("skipped") or {}).get(n, "") if state == "skipped" else ""]
    return out


def _shift_cells(shift: dict[str, list[float]]) -> list[float | None]:
    """Per compensation its move of the mark (x, y), empty cells for one the stop did not apply."""
    return [v for n in names_known() for v in (shift.get(n) or (None, None))]


def stops_csv(result: dict[str, Any], shifts: list[dict[str, list[float]]] | None = None) -> str:
    """``report_stops.csv``: one row per stop, in the order the stops were taken; ``shifts`` per stop
    (daemon/compute/report_shifts.py: how far each applied compensation moved the mark), empty cells
    without."""
    names = _direction_names(result)
    out: list[list[Any]] = [stops_columns()]
    for i, m in enumerate(result.get("marks") or []):
        s = m.get("sigma") or {}
        parts = s.get("parts_mm") or {}
        uv = m.get("uv") or [None, None]
        out.append([i, m.get("k"), names.get(m.get("k", 0), ""), m["heading_deg"], *m["abs_xyz"][:3], *uv[:2],
                    m.get("std_mm"), s.get("tracker_mm"), s.get("tracker_source"),
                    s.get("tracker_distance_mm"),
                    s.get("heading_rad"), s.get("heading_source"), *[parts.get(p) for p in SIGMA_PARTS],
                    *_comp_cells(m.get("compensation")),
                    *_shift_cells(shifts[i] if shifts else {})])
    return _csv(out)
