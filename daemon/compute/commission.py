"""``ritactl commission``'s verdicts: each unverified device assumption (docs/operations.md, "Unverified
assumptions") judged from the run's stored observations (daemon/worker/commission.py), one check each.

A check is ``{device, name, verdict, value, detail}``: ``verdict`` pass, fail, warn or skip (not measurable
in this run, and why), ``value`` the measured figure, ``detail`` the reason or what to do. The result's
verdict is ``fail`` with any failed check, ``warn`` with any warning, else ``ok``; skips are listed, not
counted. The base's checks are the conformance kit's (drivers/robot_conformance*.py), which ritad ran on its
port and returned already judged: they are taken as stored.
"""
from __future__ import annotations

import statistics
from typing import Any, Iterator

from calibration import __version__ as calib_version
from daemon.bus.clockmap import ClockMap
from daemon.bus.procedures import COMMISSION
from daemon.compute.commission_camera import Check, camera_checks

RESULT_SCHEMA = 1
#: record-time steps within this share of the rate's period count as on time (a record's own jitter)
STEP_TOL = 0.10
#: the median step may differ from the period by this share (1 %: the tracker's clock against the rate)
STEP_MEDIAN_TOL = 0.01
#: the share of steps that must be on time
STEPS_ON_TIME = 0.99
#: packets per second within this share of the expected rate (a packet more or less over a short run)
PACKET_RATE_TOL = 0.15
#: frame read-back: anything further from the identity than this is a frame
IDENTITY_TOL = 1e-9
#: the records' time σ (99th percentile): pass ≤ 0.5 ms, the error the clock map's acceptance allows at p99
#: (docs/architecture.md, "Time"); warn ≤ 5 ms, its latency prior (no better than arrival times); else fail
SIGMA_PASS_NS, SIGMA_WARN_NS = 500_000, 5_000_000
#: the map's window (ClockMap's default): a shorter run cannot tell the drift, and its σ says so
SIGMA_WINDOW_S = 60.0
#: the approach stream's clock-map bins (daemon/worker/stream.py CLOCK_BIN_S): one packet each at any rate
STREAM_BIN_S = 0.01
#: plausible readings of air on a factory floor (°C, mbar, %RH): outside, a sensor fault or a unit mix-up
#: (°F read as °C, inHg or kPa as mbar), or a value typed in wrong
PLAUSIBLE_ENV = {"temperature": (0.0, 40.0, "°C"), "pressure": (500.0, 1100.0, "mbar"),
                 "humidity": (0.0, 100.0, "%RH")}


def check(device: str, name: str, verdict: str, value: str, detail: str = "") -> Check:
    return {"device": device, "name": name, "verdict": verdict, "value": value, "detail": detail}


def _tracker(name: str, ok: bool, value: str, detail: str = "") -> Check:
    return check("tracker", name, "pass" if ok else "fail", value, detail)


def record_steps(t: dict[str, Any]) -> Check:
    """Consecutive records' device times step by the rate's period: lTime1/lTime2 are s and µs."""
    rate = float(t["rate_hz"])
    times = [u for p in t["packets"] if p.get("device_us") for u in p["device_us"]]
    if len(times) < 3:
        return _tracker("record_time", False, f"{len(times)} records with a device time",
                        "the stream carried no record times: is the tracker streaming?")
    period = 1e6 / rate
    steps = [b - a for a, b in zip(times, times[1:])]
    median = statistics.median(steps)
    on_time = sum(1 for s in steps if abs(s - period) <= STEP_TOL * period) / len(steps)
    value = (f"median step {median:.0f} µs at {rate:g} Hz (period {period:.0f} µs); {on_time:.1%} of "
             f"{len(steps)} steps within {STEP_TOL:.0%}")
    back = min(steps)
    if back <= 0:
        return _tracker("record_time", False, value, f"a record time went back or repeated ({back} µs)")
    ok = abs(median - period) <= max(1.0, STEP_MEDIAN_TOL * period) and on_time >= STEPS_ON_TIME
    return _tracker("record_time", ok, value, "" if ok else "record times are not s + µs at the asked rate")


def packet_rate(t: dict[str, Any], info: dict[str, Any]) -> Check:
    """Stream packets per second of the tracker's clock (each packet's last record time; by arrival when the
    records carry none), against the rate the tracker read back, or the one asked when it refused it."""
    stamped = [p["device_us"][-1] * 1000 for p in t["packets"] if p.get("device_us")]
    times = stamped if len(stamped) == len(t["packets"]) else [int(p["host_time_ns"]) for p in t["packets"]]
    clock = "the tracker's clock" if times is stamped else "arrival"
    asked, taken = info.get("packet_rate_asked"), info.get("packet_rate")
    want = taken if taken is not None else asked
    if len(times) < 3 or want is None or times[-1] <= times[0]:
        return _tracker("packet_rate", False, f"{len(times)} packets", "too few packets, or no rate known")
    measured = (len(times) - 1) / ((times[-1] - times[0]) / 1e9)
    value = f"{measured:.1f} packets/s over {len(times)} packets ({clock}); expected {want:g}/s"
    if taken is None:
        value += f" (asked {asked}; the tracker did not take ES_SP_TcpDataPacketRate)"
    if float(t["rate_hz"]) < float(want):
        return check("tracker", "packet_rate", "warn", value, f"records at {t['rate_hz']:g} Hz are fewer "
                     "than the packets: run again with a higher --tracker-rate-hz")
    ok = abs(measured - want) <= PACKET_RATE_TOL * want
    return _tracker("packet_rate", ok, value, "" if ok else "the tracker does not stream at the rate set")


def _not_identity(values: dict[str, Any], scale: bool) -> bool:
    return any(abs(float(v) - (1.0 if k == "scale" else 0.0)) > IDENTITY_TOL for k, v in values.items()
               if scale or k != "scale")


def _frame_text(values: dict[str, Any]) -> str:
    v = [float(values.get(k, 0.0)) for k in ("val1", "val2", "val3", "rot1", "rot2", "rot3")]
    text = f"({v[0]:g}, {v[1]:g}, {v[2]:g}) mm, ({v[3]:g}, {v[4]:g}, {v[5]:g})°"
    return text + (f", scale {float(values['scale']):g}" if "scale" in values else "")


def frame_cleared(rb: dict[str, Any]) -> Check:
    """Both apply flags off and both frames the identity: points are in the tracker's own frame."""
    found = []
    for key, flag in (("transformation", "apply_transformation_params"),
                      ("station_orientation", "apply_station_orientation_params")):
        values = rb.get(key) or {}
        if int(rb.get(flag, 1)) or _not_identity(values, key == "transformation"):
            state = "applied" if int(rb.get(flag, 1)) else "set, not applied"
            found.append(f"{key.replace('_', ' ')} {state}: {_frame_text(values)}")
    if not found:
        return _tracker("frame_cleared", True, "transformation, station orientation: identity, not applied")
    return _tracker("frame_cleared", False, "; ".join(found),
                    "another client's frame: points are not in the tracker's frame (docs/emscon.md)")


def environment(rb: dict[str, Any]) -> Check:
    """The weather monitor measures and the refraction uses plausible readings."""
    env, status = rb.get("environment") or {}, str(rb.get("weather_monitor_status"))
    value = ", ".join(f"{k} {float(env[k]):g} {u}" for k, (_, _, u) in PLAUSIBLE_ENV.items() if k in env)
    value = f"weather monitor {status}; {value or 'no environment read'}"
    bad = [f"{k} {float(env.get(k, float('nan'))):g} outside {lo:g}-{hi:g} {u}"
           for k, (lo, hi, u) in PLAUSIBLE_ENV.items() if not lo <= float(env.get(k, float("nan"))) <= hi]
    if bad:
        return _tracker("environment", False, value, "; ".join(bad) + ": a sensor fault or a unit mix-up")
    if status != "ReadAndCalculateRefractions":
        return check("tracker", "environment", "warn", value, "the refraction does not follow measured air: "
                     "connect the weather monitor, or set [tracker] temperature_c/pressure_mbar/humidity_rh")
    return _tracker("environment", True, value)


def _mapped_sigmas(packets: list[dict[str, Any]]) -> list[int]:
    """Each record's time σ (ns) when the run's packets are mapped as the approach stream maps them
    (daemon/worker/stream.py: each packet's last record against its arrival, 10 ms bins, µs stamps)."""
    cm = ClockMap(bin_s=STREAM_BIN_S, resolution_ns=1000)
    stamped = [p for p in packets if p.get("device_us")]
    for p in sorted(stamped, key=lambda p: p["device_us"][-1]):
        cm.add(int(p["device_us"][-1]) * 1000, int(p["host_time_ns"]))
    return [int(s) for s in cm.map_many([int(u) * 1000 for p in stamped for u in p["device_us"]])[1]]


def clock_sigma(t: dict[str, Any]) -> Check:
    """The records' times on the host's clock: the σ of the run's records mapped as the approach stream maps
    them (99th percentile), judged over a full window of the map (a shorter run states the drift's prior, not
    the tracker); ritad's own map of the tracker (``tracker.status`` clock, at its newest packet) is shown."""
    sigmas = sorted(_mapped_sigmas(t.get("packets") or []))
    if not sigmas:
        return _tracker("clock_sigma", False, "no clock map", "no stream packet with record times")
    p99, ritad = sigmas[int(0.99 * (len(sigmas) - 1))], (t.get("clock") or {}).get("sigma_ns")
    value = f"σ p50 {statistics.median(sigmas) / 1e3:.0f} µs, p99 {p99 / 1e3:.0f} µs, {len(sigmas)} records"
    value += f"; ritad's map {ritad / 1e3:.0f} µs at its newest packet" if ritad is not None else ""
    if float(t.get("duration_s") or 0) < SIGMA_WINDOW_S:
        return check("tracker", "clock_sigma", "skip", value, f"a run under {SIGMA_WINDOW_S:.0f} s states "
                     "the drift's prior: judged with --duration-s 60 or more")
    verdict = "pass" if p99 <= SIGMA_PASS_NS else "warn" if p99 <= SIGMA_WARN_NS else "fail"
    why = "" if verdict == "pass" else "record times are poorly mapped: a loaded host or a jittery link"
    return check("tracker", "clock_sigma", verdict, value, why)


def tracker_checks(t: dict[str, Any]) -> Iterator[Check]:
    rb = t.get("readback") or {}
    yield record_steps(t)
    yield packet_rate(t, t.get("info") or {})
    yield frame_cleared(rb)
    yield environment(rb)
    yield clock_sigma(t)


def base_checks(b: dict[str, Any]) -> Iterator[Check]:
    """The kit's checks as ritad returned them, and the clock's restarts ritad's map saw since connecting."""
    for c in b.get("checks") or []:
        yield check("base", str(c["name"]), str(c["verdict"]), str(c["value"]), str(c.get("detail", "")))
    resets = (b.get("clock") or {}).get("resets")
    if resets is not None:
        why = "" if resets == 0 else "t_us wrapped or the base restarted (docs/robot-protocol.md, t_us)"
        yield check("base", "t_us_resets", "pass" if resets == 0 else "fail",
                    f"the base's clock went back {resets} time(s) since ritad connected", why)


CHECKS = {"tracker": tracker_checks, "camera": camera_checks, "base": base_checks}


def device_checks(name: str, d: dict[str, Any]) -> list[Check]:
    """One device's checks; a device that could not be measured is one failed check naming why."""
    if d.get("error"):
        return [check(name, "measured", "fail", d["error"], "fix this first: no other check of it ran")]
    return list(CHECKS[name](d))


def table(checks: list[Check]) -> str:
    """The checks as a Markdown table (a bar inside a cell would split it: written \\|)."""
    def cell(text: str) -> str:
        return text.replace("\n", " ").replace("|", "\\|")

    rows = ["| device | check | verdict | measured | detail |", "|---|---|---|---|---|"]
    rows += [f"| {c['device']} | {c['name']} | {c['verdict'].upper()} | {cell(c['value'])} | "
             f"{cell(c['detail'])} |" for c in checks]
    return "\n".join(rows) + "\n"


def message(c: Check) -> str:
    """A failed or warned check as one line of the result's messages."""
    why = f" ({c['detail']})" if c["detail"] else ""
    return f"{c['device']} {c['name']}: {c['verdict']}: {c['value']}{why}"


def compute_commission(obs: dict[str, Any], load: Any = None) -> dict[str, Any]:
    """Every stored device's checks; the verdict the worst of them (skips not counted)."""
    checks = [c for name in obs.get("devices", []) if name in obs for c in device_checks(name, obs[name])]
    verdicts = {c["verdict"] for c in checks}
    verdict = "fail" if "fail" in verdicts else "warn" if "warn" in verdicts else "ok"
    messages = [message(c) for c in checks if c["verdict"] in ("fail", "warn")]
    return {"schema": RESULT_SCHEMA, "procedure": COMMISSION.name, "software": calib_version,
            "verdict": verdict, "messages": messages, "checks": checks, "table_markdown": table(checks)}
