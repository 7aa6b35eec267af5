"""An experiment report's header: what a metrologist files with the figures, worded once for report.md
and the plot.

Job, date, dataset, mark, calibration, compensations, verdict with its reasons, and each goal
``met`` or ``MISSED`` (daemon/bus/figures.py), taken from the result as written
(daemon/compute/files.py adds ``created`` and ``dataset``). A field the result does not hold is
shown as ``not recorded``, never left out: a reader sees the gap.
"""
from __future__ import annotations

from pathlib import PurePath
from typing import Any

from daemon.bus.figures import (EXPERIMENT_GOALS, counted, counted_from, experiment_goal_lines, goal_text,
                                worse_lines)

#: how the plot and the tables name directions (calibration/metrics.py DIRECTION_NAMES, the paper's table)
ANGLE_CONVENTION = ("heading ψ: the robot's forward (x) axis in ACS, from ACS +x towards +y; the paper's "
                    "names: up 0°, upleft 45°, left 90°, downleft 135°, down 180°, downright −135°, "
                    "right −90°, upright −45°")
NOT_RECORDED = "not recorded"


def _xy(v: Any, fmt: str = ".4f") -> str:
    """``(x, y)`` of a 2- or 3-vector in mm, signed, or :data:`NOT_RECORDED`."""
    if not isinstance(v, (list, tuple)) or len(v) < 2:
        return NOT_RECORDED
    return f"({float(v[0]):+{fmt}}, {float(v[1]):+{fmt}}) mm"


def dataset_id(result: dict[str, Any]) -> str:
    """The dataset's folder name (procedures/<job>): the id the robot's files and ``ritactl fetch`` use."""
    return PurePath(str(result.get("dataset") or "")).name or NOT_RECORDED


def mark_text(result: dict[str, Any]) -> str:
    """The mark: its kind and size as the job asked, where it was approached, and where it was measured."""
    p = result.get("params") or {}
    kind = p.get("kind") or NOT_RECORDED
    size = f", size {float(p['mark_size_mm']):g} mm" if p.get("mark_size_mm") is not None else ""
    metrics = result.get("metrics") or {}
    mean = (metrics.get("all") or {}).get("mean")
    fit = metrics.get("fit") or {}
    return (f"{kind}{size}; approached at ACS {_xy(p.get('mark_xy'), '.1f')}; mean of all stops ACS "
            f"{_xy(mean)}; fitted mark M ACS {_xy(fit.get('M'))}")


def compensation_lines(comp: dict[str, Any] | None) -> list[str]:
    """Per requested compensation: at how many stops it applied, what it applied, why the others skipped it
    (each reason once, with its count)."""
    if not comp:
        return [NOT_RECORDED]
    stops = comp.get("stops", 0)
    if not comp.get("requested"):
        return ["none requested"]
    out = []
    for name in comp["requested"]:
        n = (comp.get("applied") or {}).get(name, 0)
        what = _applied_value(name, comp) if n else ""
        line = f"{name}: applied at {n} of {stops} stops{what}"
        counts = (comp.get("skipped_stops") or {}).get(name)
        reasons = counted_from(counts) if counts else counted((comp.get("skipped") or {}).get(name) or [])
        out.append(line + (f"; skipped: {'; '.join(reasons)}" if reasons else ""))
    return out


def _applied_value(name: str, comp: dict[str, Any]) -> str:
    """What a compensation applied, from the calibration the experiment measured with."""
    if name == "bias" and comp.get("robot_bias_mm") is not None:
        return f" (robot-frame bias b = {_xy(comp['robot_bias_mm'])}, the calibration's)"
    if name == "tilt" and comp.get("imu_offset_deg") is not None:
        r, p = comp["imu_offset_deg"]
        return f" (inclinometer offset roll {float(r):+.4f}°, pitch {float(p):+.4f}°)"
    if name == "mount" and comp.get("reflector_mount_los_mm") is not None:
        los = float(comp["reflector_mount_los_mm"])
        return f" (reflector mount offset {los:+.4f} mm along the line of sight)"
    if name == "heading_fit" and comp.get("heading_weight") is not None:
        return f" (weight {float(comp['heading_weight']):.2f} of the fitted bend)"
    return ""


def bias_applied(comp: dict[str, Any]) -> str:
    """What the b fitted to the marks is, by where the calibration's b was applied (one rule for report.md
    and report_metrics.csv): ``every`` stop (the fit is what is left after it), ``some`` stops only (the
    fit mixes both) or ``none`` (the fit is the whole bias)."""
    n, stops = (comp.get("applied") or {}).get("bias", 0), comp.get("stops", 0)
    if n and n == stops and comp.get("robot_bias_mm") is not None:
        return "every"
    return "some" if n else "none"


def bias_lines(result: dict[str, Any]) -> list[str]:
    """The robot-frame bias under names that say what each is (one number, one meaning): the calibration's
    b applied at every stop and what is left after it, or the b fitted to these marks; and the b fitted
    jointly with heading_fit's weight, the one ``store_bias`` stores (added to an applied b)."""
    comp, fit = result.get("compensation") or {}, (result.get("metrics") or {}).get("fit") or {}
    n, stops = (comp.get("applied") or {}).get("bias", 0), comp.get("stops", 0)
    out: list[str] = []
    applied = bias_applied(comp)
    if applied == "every":
        out.append(f"the calibration's b {_xy(comp['robot_bias_mm'])} applied at every stop; left after it, "
                   f"fitted to these marks: {_xy(fit.get('b'))}")
    elif fit:
        mixed = f" (b applied at {n} of {stops} stops only: the fit mixes both)" if applied == "some" else ""
        out.append(f"fitted to these marks: {_xy(fit.get('b'))}{mixed}")
    joint = (result.get("heading_weight") or {}).get("b_mm")
    if joint is not None:
        asked = (result.get("params") or {}).get("store_bias")
        store = "this job asked to store it: result.json's messages say whether it was" if asked else \
            "this job did not ask to store it"
        out.append(f"fitted jointly with heading_fit's weight: {_xy(joint)} (what store_bias stores; "
                   f"{store})")
    return out or [NOT_RECORDED]


def verdict_lines(result: dict[str, Any]) -> list[str]:
    """The verdict, then each reason (the result's messages) and each check that did not pass."""
    out = [str(result.get("verdict") or NOT_RECORDED)]
    word = "note" if result.get("verdict") == "ok" else "reason"  # an ok result's messages explain nothing
    out += [f"{word}: {m}" for m in result.get("messages") or []]
    for name, check in (result.get("checks") or {}).items():
        if isinstance(check, dict) and check.get("ok") is False and check.get("message") not in result.get(
                "messages", []):
            out.append(f"check {name} not passed: {check.get('message') or 'no reason given'}")
    return out


def without_lines(result: dict[str, Any], compared: dict[str, Any]) -> list[str]:
    """The goals' figures without any compensation, each met or MISSED, and a ``WORSE`` line for each the
    compensations made worse, naming the one that did (left out alone) and the possible reasons; why they
    are not given, when not. ``compared``: see :func:`header`."""
    comp, plain, why = result.get("compensation") or {}, compared.get("plain"), compared.get("why") or ""
    if plain is None:
        return [f"not computed: {why}" if why else "the same: no compensation was applied"]
    out = []
    for label, key, goal in EXPERIMENT_GOALS:
        out.append(goal_text(plain.get(key), goal, label=f"{label} without compensation"))
        with_ = (result.get("metrics") or {}).get(key)
        if isinstance(with_, (int, float)) and isinstance(plain.get(key), (int, float)):
            left = {n: float(m[key]) for n, m in (compared.get("left_out") or {}).items()}
            out += worse_lines(label, float(plain[key]), float(with_), comp, key.startswith("enclosing"),
                               left)
    return out


def header(result: dict[str, Any], compared: dict[str, Any] | None = None) -> list[tuple[str, list[str]]]:
    """(field, its lines) in the order report.md and the plot show them (a line indented by ``  - ``: under
    the one before). ``compared`` (daemon/compute/files.py from report_shifts.py): ``why`` the per-stop
    shifts are not given ("" when they are), the metrics without compensation (``plain``) and with each
    applied compensation left out alone (``left_out``: name → metrics)."""
    compared = compared or {}
    recomputed = result.get("recomputed_with")
    no_shifts = compared.get("why") or ""
    shifts = [f"per-stop shifts NOT in report_stops.csv: {no_shifts}"] if no_shifts else []
    return [("job", [str(result.get("job") or NOT_RECORDED)]),
            ("date", [f"{result.get('created') or NOT_RECORDED} (UTC, result written)"]),
            ("dataset", [f"{dataset_id(result)} ({result.get('dataset') or NOT_RECORDED})"]),
            ("mark", [mark_text(result)]),
            ("calibration", [str(result.get("calibration_job") or NOT_RECORDED)]),
            ("compensations", compensation_lines(result.get("compensation")) + shifts),
            ("robot-frame bias", bias_lines(result)),
            ("verdict", verdict_lines(result)),
            ("goals", experiment_goal_lines(result.get("metrics")) or [NOT_RECORDED]),
            ("without compensation", without_lines(result, compared)),
            ("software", [f"calibration {result.get('software') or NOT_RECORDED}"]
             + ([f"recomputed offline with other {', '.join(recomputed)}"] if recomputed else [])),
            ("angles", [ANGLE_CONVENTION])]


def _bold_missed(line: str) -> str:
    return line[:-len("MISSED")] + "**MISSED**" if line.endswith(": MISSED") else line


def _bullet(line: str) -> str:
    """A header line as a Markdown bullet under its field: a line indented ``  - `` nests one deeper."""
    body = line.lstrip(" ")
    depth = (len(line) - len(body)) // 2 if body.startswith("- ") else 0
    return "  " * (depth + 1) + "- " + _bold_missed(body[2:] if depth else line)


def header_markdown(result: dict[str, Any], compared: dict[str, Any] | None = None) -> str:
    """The header block of report.md: a title, then one bullet per field (several lines: sub-bullets)."""
    n = len(result.get("marks") or [])
    k = len((result.get("metrics") or {}).get("clusters") or [])
    lines = [f"# Repeatability experiment {result.get('job') or ''}".rstrip(), "",
             f"The mark measured from {k} directions, {n} stops (the paper's 8-direction experiment).", ""]
    for name, values in header(result, compared):
        if len(values) == 1:
            lines.append(f"- **{name}**: {_bold_missed(values[0])}")
        else:
            lines.append(f"- **{name}**:")
            lines += [_bullet(v) for v in values]
    return "\n".join(lines) + "\n"
