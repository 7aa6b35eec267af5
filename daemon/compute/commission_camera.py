"""``ritactl commission``'s camera checks, from the stored ``camera.status`` snapshots and timed captures.

PTP role and lock, the offset from the master, the timestamp's unit and where it latches, the link speed,
the packet size, resends over a stream, the pixel format (docs/operations.md, "Unverified assumptions").
"""
from __future__ import annotations

from typing import Any, Iterator

Check = dict[str, str]
#: GigE's line rate in bytes/s (SFNC's DeviceLinkSpeed unit): the PHX122S is a 1 GigE camera
GIGE_BYTES_S = 125_000_000
LINK_TOL = 0.01
#: a PTP slave's offset from its master: the goal of docs/operations.md ("below 1 µs")
PTP_OFFSET_NS = 1000
#: the camera's tick against the host's clock between captures: 1 GHz within this share (a 125 MHz tick is
#: 8× off, µs 1000×; the captures' arrival jitter of a few ms over seconds is far below)
UNIT_TOL = 0.05
#: the host and the camera on one PTP master agree to this (ns) when the latch is judged
LATCH_MARGIN_NS = 100_000
#: resend requests per streamed frame above which the link counts as struggling (docs/operations.md)
RESENDS_PER_FRAME = 0.01
LINK_COUNTERS = ("resend_requests", "lost_packets", "incomplete_frames", "lost_frames")


def _c(name: str, verdict: str, value: str, detail: str = "") -> Check:
    return {"device": "camera", "name": name, "verdict": verdict, "value": value, "detail": detail}


def _statuses(cam: dict[str, Any]) -> list[dict[str, Any]]:
    return [s for s in (cam.get(k) for k in ("status_before", "status_after", "status_end")) if s]


def ptp_role(cam: dict[str, Any]) -> Check:
    """With PTP on, the camera's port is Slave at every look, and never Master."""
    looks = _statuses(cam)
    ptp = [s.get("ptp") or {} for s in looks]
    if not any(p.get("available") for p in ptp):
        return _c("ptp_role", "skip", "the camera has no PTP", "frames are timed by the clock map")
    if not any(p.get("enabled") for p in ptp) and not (looks[0].get("settings") or {}).get("ptp"):
        return _c("ptp_role", "skip", "PTP off ([camera] ptp)", "frames timed by the clock map (~0.1-0.5 ms)")
    states = [str(p.get("status")) for p in ptp]
    value = f"PtpStatus {' → '.join(dict.fromkeys(states))} ({len(states)} looks)"
    if "Master" in states:
        return _c("ptp_role", "fail", value, "the camera won the master election: PtpSlaveOnly not honoured; "
                  "make the computer the master (ptp4l --priority1 10, docs/operations.md)")
    if any(s != "Slave" for s in states):
        return _c("ptp_role", "fail", value, "not locked to a master: is ptp4l running on the camera's NIC?")
    return _c("ptp_role", "pass", value)


def ptp_offset(cam: dict[str, Any]) -> Check:
    ptp = [s.get("ptp") or {} for s in _statuses(cam)]
    if not ptp or any(p.get("status") != "Slave" for p in ptp):
        return _c("ptp_offset", "skip", "no PTP lock", "judged only with the port Slave (ptp_role)")
    offsets = [p.get("offset_from_master_ns") for p in ptp]
    if any(o is None for o in offsets):
        return _c("ptp_offset", "warn", "no PtpOffsetFromMaster", "the camera does not report its offset")
    worst = max(abs(float(o)) for o in offsets if o is not None)
    ok = worst <= PTP_OFFSET_NS
    return _c("ptp_offset", "pass" if ok else "fail", f"offset within ±{worst:.0f} ns",
              "" if ok else f"above {PTP_OFFSET_NS} ns: check the master and the NIC's clock")


def timestamp_unit(cam: dict[str, Any]) -> Check:
    """The camera's stamps advance with the host's clock between captures: a 1 GHz tick (ns)."""
    caps = [c for c in cam.get("captures") or [] if c.get("device_time_ns") is not None]
    if len(caps) < 2:
        return _c("timestamp_unit", "skip", f"{len(caps)} captures with a device time", "no stamped frames")
    first, last = caps[0], caps[-1]
    host = int(last["host_time_ns"]) - int(first["host_time_ns"])
    ratio = (int(last["device_time_ns"]) - int(first["device_time_ns"])) / host if host > 0 else 0.0
    value = f"{ratio:.4f} ns of the camera per host ns over {host / 1e9:.2f} s"
    ok = abs(ratio - 1.0) <= UNIT_TOL
    return _c("timestamp_unit", "pass" if ok else "fail", value, "" if ok else "the timestamp is not in ns")


def timestamp_latch(cam: dict[str, Any]) -> Check:
    """Taken as the exposure's start: a stamp earlier than one exposure after the trigger was asked proves it
    is not the exposure's end (the trigger goes out after the call began). Needs the stamp on the host's
    timeline, so PTP locked with the host on its master."""
    caps = [c for c in cam.get("captures") or [] if c.get("t_source") == "ptp" and c.get("exposure_us")]
    if not caps:
        return _c("timestamp_latch", "skip", "no capture timed by PTP",
                  "needs the PTP lock; else the LED bench check (docs/operations.md, Camera time and PTP)")
    # t_ns is the exposure's mid-time (device stamp + exposure / 2): its stamp is t_ns - exposure / 2
    leads = [(int(c["t_ns"]) - float(c["exposure_us"]) * 500 - int(c["call_ns"]),
              float(c["exposure_us"]) * 1e3) for c in caps]
    lead, exposure = min(leads)
    value = f"stamp {lead / 1e3:.0f} µs after the capture was asked; exposure {exposure / 1e3:.0f} µs"
    if lead < -LATCH_MARGIN_NS:
        return _c("timestamp_latch", "warn", value, "a stamp before the trigger: the host is not on the "
                  "camera's PTP master (docs/operations.md, Camera time and PTP)")
    if lead + LATCH_MARGIN_NS < exposure:
        return _c("timestamp_latch", "pass", value, "before the exposure could end: stamped at its start")
    return _c("timestamp_latch", "skip", value, "inconclusive (the trigger's latency is longer than the "
              "exposure): do the LED bench check of docs/operations.md")


def link_speed(cam: dict[str, Any]) -> Check:
    speed = (cam.get("status_before") or {}).get("device_link_speed")
    if speed is None:
        return _c("link_speed", "skip", "no DeviceLinkSpeed", "not reported: 125 MB/s assumed")
    value = f"DeviceLinkSpeed {float(speed):.0f}"
    if abs(float(speed) - GIGE_BYTES_S) <= LINK_TOL * GIGE_BYTES_S:
        return _c("link_speed", "pass", value + " bytes/s (1 GigE)")
    unit = " (Mbps? the driver reads a value this small as Mbps)" if float(speed) < 100_000 else ""
    return _c("link_speed", "fail", value + unit, f"expected {GIGE_BYTES_S} bytes/s on 1 GigE: a slower link "
              "(cable, switch port) or another unit")


def packet_size(cam: dict[str, Any]) -> Check:
    st = cam.get("status_before") or {}
    applied, want = st.get("applied") or {}, (st.get("settings") or {}).get("packet_size")
    got = applied.get("GevSCPSPacketSize", applied.get("DeviceStreamChannelPacketSize"))
    warned = [w for w in st.get("warnings") or [] if "acket" in w]
    value = f"packet size {got} (configured {want if want is not None else 'none: the camera default'})"
    if got is None:
        return _c("packet_size", "warn", value, "the camera reports no packet size node")
    if warned or (want is not None and int(got) != int(want)):
        return _c("packet_size", "fail", value, "; ".join(warned) or "the camera did not take it")
    return _c("packet_size", "pass", value)


def resends(cam: dict[str, Any]) -> Check:
    """The link's counters over the stream: no lost or incomplete frames, resends near 0."""
    before, after = cam.get("status_before") or {}, cam.get("status_after") or {}
    lb, la = before.get("link") or {}, after.get("link") or {}
    frames = int(after.get("frames") or 0) - int(before.get("frames") or 0)
    if not la or all((la.get("source") or {}).get(k) is None for k in LINK_COUNTERS):
        return _c("resends", "warn", f"{frames} frames; no link counter", "the producer counts nothing")
    delta = {k: int(la.get(k) or 0) - int(lb.get(k) or 0) for k in LINK_COUNTERS}
    counts = ", ".join(f"{v} {k}" for k, v in delta.items())
    value = f"{frames} frames in {cam.get('duration_s')} s: {counts}"
    if frames <= 0:
        return _c("resends", "fail", value, "no frame streamed")
    if delta["lost_frames"] or delta["incomplete_frames"]:
        return _c("resends", "fail", value, "frames lost or incomplete: MTU, packet size or throughput limit")
    if delta["resend_requests"] > RESENDS_PER_FRAME * frames:
        return _c("resends", "warn", value, "the link loses packets (resends save the frames)")
    return _c("resends", "pass", value)


def pixel_format(cam: dict[str, Any]) -> Check:
    st = cam.get("status_before") or {}
    applied, want = st.get("applied") or {}, (st.get("settings") or {}).get("pixel_format")
    got = applied.get("PixelFormat")
    mirrored = [n for n in ("ReverseX", "ReverseY") if applied.get(n) in (True, 1, "1", "True")]
    value = f"PixelFormat {got} (configured {want})" + (f"; {', '.join(mirrored)} on" if mirrored else "")
    if got is None or (want is not None and got != want) or mirrored:
        return _c("pixel_format", "fail", value, "mirrored Bayer images decode with wrong colours" if mirrored
                  else "the camera did not take the pixel format")
    return _c("pixel_format", "pass", value)


def camera_checks(cam: dict[str, Any]) -> Iterator[Check]:
    for fn in (ptp_role, ptp_offset, timestamp_unit, timestamp_latch, link_speed, packet_size, resends,
               pixel_format):
        yield fn(cam)
