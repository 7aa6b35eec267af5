"""The commissioning's verdicts from stored evidence (daemon/compute/commission*.py), on synthetic
observations: each check passes what the docs assume and fails, naming the value, what breaks it."""
from __future__ import annotations

from typing import Any, Callable

import numpy as np
import pytest

from daemon.compute.commission import clock_sigma, compute_commission, environment, record_steps, table
from daemon.compute.commission_camera import (link_speed, pixel_format, ptp_role, resends, timestamp_latch,
                                              timestamp_unit)

T0_US, HOST0_NS = 1_000_000, 1_795_000_000_000_000_000


def packets(seconds: float, rate: float = 10.0, record_hz: float = 1000.0, seed: int = 1,
            latency_s: Callable[[np.random.Generator], float] = lambda r: r.exponential(0.0005),
            tick_us: float = 1.0) -> list[dict[str, Any]]:
    """A stream of ``seconds``: packets at ``rate`` of records at ``record_hz``, each packet arriving after
    its last record plus a random latency (seeded). ``tick_us``: the device's record-time unit, in µs."""
    rng, out = np.random.default_rng(seed), []
    step = int(1e6 / record_hz)
    for k in range(int(seconds * rate)):
        us = list(range(T0_US + int(k * 1e6 / rate), T0_US + int((k + 1) * 1e6 / rate), step))
        out.append({"host_time_ns": int(HOST0_NS + us[-1] * 1000 + latency_s(rng) * 1e9), "n": len(us),
                    "device_us": [int(u / tick_us) for u in us]})
    return out


def test_record_steps_pass_at_the_rate_and_fail_naming_the_step_in_another_unit() -> None:
    assert record_steps({"rate_hz": 1000.0, "packets": packets(2)})["verdict"] == "pass"
    ms = record_steps({"rate_hz": 1000.0, "packets": packets(2, tick_us=1000.0)})  # lTime2 read as ms
    assert ms["verdict"] == "fail" and "median step 1 µs at 1000 Hz (period 1000 µs)" in ms["value"], ms


def test_clock_sigma_is_judged_over_a_full_window_only() -> None:
    good = clock_sigma({"packets": packets(60), "duration_s": 60.0})
    assert good["verdict"] == "pass" and "p99" in good["value"], good
    short = clock_sigma({"packets": packets(10), "duration_s": 10.0})
    assert short["verdict"] == "skip" and "--duration-s 60" in short["detail"], short
    noisy = packets(60, latency_s=lambda r: r.uniform(0, 0.05))
    jittery = clock_sigma({"packets": noisy, "duration_s": 60.0})
    assert jittery["verdict"] == "warn", jittery  # 0-50 ms of arrival jitter: σ of ms


def test_environment_names_an_implausible_reading_and_warns_without_a_monitor() -> None:
    env = {"temperature": 20.0, "pressure": 29.92, "humidity": 45.0}  # inHg where mbar is wanted
    bad = environment({"weather_monitor_status": "ReadAndCalculateRefractions", "environment": env})
    assert bad["verdict"] == "fail" and "pressure 29.92 outside 500-1100 mbar" in bad["detail"], bad
    off = environment({"weather_monitor_status": "NotConnected", "environment": {**env, "pressure": 1013.0}})
    assert off["verdict"] == "warn" and "NotConnected" in off["value"], off


def _status(**kw: Any) -> dict[str, Any]:
    st = {"settings": {"pixel_format": "BayerRG8", "ptp": True, "packet_size": None},
          "applied": {"PixelFormat": "BayerRG8", "GevSCPSPacketSize": 8192}, "warnings": [],
          "ptp": {"available": True, "enabled": True, "status": "Slave", "offset_from_master_ns": 120},
          "device_link_speed": 125_000_000, "frames": 0,
          "link": {"resend_requests": 0, "lost_packets": 0, "incomplete_frames": 0, "lost_frames": 0,
                   "source": {"resend_requests": "StreamResendRequestCount"}}}
    return {**st, **kw}


def test_camera_checks_name_what_breaks_them() -> None:
    master = {"status_before": _status(), "status_after": _status(ptp={"available": True, "enabled": True,
                                                                        "status": "Master"})}
    assert ptp_role(master)["verdict"] == "fail" and "Slave → Master" in ptp_role(master)["value"]
    mbps = link_speed({"status_before": _status(device_link_speed=1000)})
    assert mbps["verdict"] == "fail" and "DeviceLinkSpeed 1000 (Mbps?" in mbps["value"], mbps
    mirrored = pixel_format({"status_before": _status(applied={"PixelFormat": "BayerRG8", "ReverseX": True})})
    assert mirrored["verdict"] == "fail" and "ReverseX on" in mirrored["value"], mirrored
    lost = resends({"status_before": _status(), "duration_s": 60, "status_after": _status(
        frames=540, link={**_status()["link"], "lost_frames": 3})})
    assert lost["verdict"] == "fail" and "540 frames in 60 s" in lost["value"], lost
    assert "3 lost_frames" in lost["value"], lost


def _captures(stamp_after_call_us: float, tick: float = 1.0) -> list[dict[str, Any]]:
    """Five captures 0.25 s apart, PTP stamps ``stamp_after_call_us`` after the call; 2 ms exposure."""
    out = []
    for k in range(5):
        call = HOST0_NS + int(k * 0.25e9)
        stamp = call + int(stamp_after_call_us * 1e3)
        out.append({"call_ns": call, "reply_ns": call + 20_000_000, "exposure_us": 2000.0, "t_source": "ptp",
                    "t_ns": stamp + 1_000_000, "host_time_ns": call + 15_000_000,
                    "device_time_ns": int((stamp + 37_000_000_000) * tick)})
    return out


def test_the_timestamp_latch_and_unit_from_timed_captures() -> None:
    assert timestamp_latch({"captures": _captures(300)})["verdict"] == "pass"  # before the exposure could end
    late = timestamp_latch({"captures": _captures(5000)})
    assert late["verdict"] == "skip" and "LED bench check" in late["detail"], late  # inconclusive, said so
    assert timestamp_unit({"captures": _captures(300)})["verdict"] == "pass"
    us = timestamp_unit({"captures": _captures(300, tick=1e-3)})  # a µs counter
    assert us["verdict"] == "fail" and us["value"].startswith("0.0010 ns"), us


@pytest.mark.parametrize("verdicts, overall", [(("pass", "skip"), "ok"), (("pass", "warn", "skip"), "warn"),
                                               (("warn", "fail"), "fail")])
def test_the_verdict_is_the_worst_check_and_skips_do_not_count(verdicts: tuple[str, ...],
                                                                overall: str) -> None:
    checks = [{"name": f"c{i}", "verdict": v, "value": f"v{i} | bar", "detail": ""}
              for i, v in enumerate(verdicts)]
    result = compute_commission({"devices": ["base"], "base": {"state": "READY", "checks": checks}})
    assert result["verdict"] == overall
    assert len(result["messages"]) == sum(v in ("warn", "fail") for v in verdicts)
    assert "v0 \\| bar" in table(result["checks"])  # a bar in a value does not split the Markdown table
