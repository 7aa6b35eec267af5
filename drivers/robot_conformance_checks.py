"""The conformance kit's checks that need no motion: each a function of a :class:`Link`, reusable by the
commissioning procedure (``ritactl commission``: the base's clock, its round-trip latency).

Every rule checked is one of docs/robot-protocol.md; the limits are robot_protocol.py's constants.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass

from drivers import robot_protocol as rp
from drivers.robot_conformance_link import Check, Link, Received, ms, seq_of, verdict

#: how far the base's crystal and the host's may run apart (ppm): two ±500 ppm clocks at worst
CLOCK_PPM = 1000.0
#: a version-1 VERSION reply's fields after its kind (seq, protocol, model, firmware, serial, capabilities)
VERSION_V1_FIELDS = 6


def wire_s(n_bytes: int, baudrate: int) -> float:
    """Time ``n_bytes`` take on an 8N1 line (10 bits a byte)."""
    return n_bytes * 10.0 / baudrate


def check_stop_before_hello(link: Link, boot_s: float = rp.BOOT_S) -> Check:
    """STOP is accepted before any HELLO (asked again within the boot window: a base may be booting).
    Its value starts "nothing read" when the base said nothing at all: it cannot be reached."""
    deadline = time.monotonic() + boot_s + link.timeout
    while time.monotonic() < deadline:
        seq, got, rtt = link.ask("STOP")
        if got is not None:
            ok = (
                got.msg is not None
                and got.msg.kind == "ACK"
                and got.msg.fields[1:2] == ("STOP",)
                and seq_of(got.msg) == seq
            )
            return verdict("stop_before_hello", ok, f"reply {_text(got)} in {ms(rtt)}")
    if not link.log and link.ask("HELLO", 1)[1] is None:
        return verdict("stop_before_hello", False, f"nothing read in {boot_s + link.timeout:.1f} s")
    if any(r.msg is not None and r.msg.kind == "VERSION" for r in link.log):
        return verdict("stop_before_hello", False, "STOP never acknowledged", "HELLO is answered")
    good = sum(1 for r in link.log if r.msg is not None)
    return verdict(
        "stop_before_hello",
        False,
        f"no reply to STOP in {boot_s + link.timeout:.1f} s",
        f"{len(link.log)} lines read, {good} well formed",
    )


def _hello(link: Link, *fields: object) -> tuple[int, Received | None]:
    seq, got, _ = link.ask("HELLO", *fields)
    return seq, got


def check_versions(link: Link) -> tuple[Check, int, list[str]]:
    """HELLO 9 is refused (NAK VERSION); each version the base speaks answers exactly as that version;
    the fallback 3 → 2 → 1 finds the newest. Returns the check, the newest version and its capabilities,
    and leaves the line in a session of that version (version 3 with the default host timeout)."""
    problems: list[str] = []
    _, got = _hello(link, 9)
    if got is None or got.msg is None or got.msg.kind != "NAK" or got.msg.fields[1:2] != ("VERSION",):
        problems.append(f"HELLO 9 answered {_text(got)}, not NAK VERSION")
    spoken: dict[int, list[str]] = {}
    for version in (1, 2, 3):
        extra = (rp.DEFAULT_HOST_TIMEOUT_MS,) if version == 3 else ()
        seq, got = _hello(link, version, *extra)
        msg = got.msg if got else None
        if msg is not None and msg.kind == "NAK" and msg.fields[1:2] == ("VERSION",):
            continue
        if msg is None or msg.kind != "VERSION" or seq_of(msg) != seq or msg.fields[1:2] != (str(version),):
            problems.append(f"HELLO {version} answered {_text(got)}")
            continue
        caps = rp.capabilities(msg.fields[5]) if len(msg.fields) > 5 else []
        spoken[version] = caps
        problems += _version_rules(link, version, msg, caps)
    if not spoken:
        return verdict("versions", False, "speaks none of 1, 2, 3", "; ".join(problems)), 0, []
    newest = max(spoken)
    if sorted(spoken) != list(range(1, newest + 1)):
        problems.append(f"speaks {sorted(spoken)}: a base of version N speaks every version up to N")
    _hello(link, newest, *((rp.DEFAULT_HOST_TIMEOUT_MS,) if newest == 3 else ()))
    value = f"speaks {'/'.join(map(str, sorted(spoken)))}; capabilities {'+'.join(spoken[newest]) or 'none'}"
    return verdict("versions", not problems, value, "; ".join(problems)), newest, spoken[newest]


def _version_rules(link: Link, version: int, msg: rp.Message, caps: list[str]) -> list[str]:
    """What a session of ``version`` must look like: its VERSION and STATUS fields."""
    problems = []
    newer = (
        {rp.CAP_CLOCK, rp.CAP_STATE, rp.CAP_WATCHDOG}
        if version == 1
        else {rp.CAP_WATCHDOG}
        if version == 2
        else set()
    )
    if newer & set(caps) or version < 3 and len(msg.fields) != VERSION_V1_FIELDS:
        problems.append(f"version-{version} VERSION {msg.body()!r} has newer fields or flags")
    if version == 3 and rp.CAP_WATCHDOG in caps and msg.fields[6:7] != (str(rp.DEFAULT_HOST_TIMEOUT_MS),):
        problems.append(f"version-3 VERSION {msg.body()!r} does not echo host_timeout_ms 300")
    _, got, _ = link.ask("STATUS")
    want = rp.STATUS_V1_FIELDS + (1 if version >= 2 and rp.CAP_CLOCK in caps else 0)
    if got is None or got.msg is None or got.msg.kind != "STATUS" or len(got.msg.fields) != want:
        problems.append(f"version-{version} STATUS {_text(got)} has not {want} fields")
    return problems


def _text(got: Received | None) -> str:
    return "nothing" if got is None else repr(got.raw.decode(errors="replace"))


def check_naks(link: Link) -> list[Check]:
    """Each NAK reason the base owes without a motion, with its seq rule; noise gets no reply."""
    out = []
    body = f"STATUS,{link.next_seq()}"
    wrong = f"{int(rp.checksum(body), 16) ^ 0x5A:02X}"
    for name, line, reason, want_seq in (
        ("nak_checksum", f"${body}*{wrong}\r\n".encode(), "CHECKSUM", None),
        ("nak_unknown", rp.encode("JUMP", link.next_seq()), "UNKNOWN", link.seq),
        ("nak_range", rp.encode("MOVE", link.next_seq(), 99999, 50), "RANGE", link.seq),
        ("nak_syntax", rp.encode("MOVE", link.next_seq(), "far", 50), "SYNTAX", link.seq),
    ):
        got = link.ask_line(line)
        msg = got.msg if got else None
        ok = (
            msg is not None and msg.kind == "NAK" and msg.fields[1:2] == (reason,) and seq_of(msg) == want_seq
        )
        out.append(verdict(name, ok, f"reply {_text(got)}", f"want NAK,{want_seq or ''},{reason}"))
    got = link.ask_line(b"\x00noise ~~ no frame\r\n", timeout=0.3)
    out.append(verdict("noise_ignored", got is None, "no reply" if got is None else f"reply {_text(got)}"))
    seq = link.next_seq()
    body = f"STATUS,{seq}"
    got = link.ask_line(f"${body}*{rp.checksum(body).lower()}\r\n".encode())
    ok = got is not None and got.msg is not None and got.msg.kind == "STATUS" and seq_of(got.msg) == seq
    out.append(verdict("lowercase_hex", ok, f"reply {_text(got)}", "a checksum in lower case is accepted"))
    return out


def check_retry_status(link: Link) -> Check:
    """A STATUS resent with the same seq is answered again with that seq (safe to execute twice)."""
    seq = link.next_seq()
    line = rp.encode("STATUS", seq)
    replies = [link.ask_line(line), link.ask_line(line)]
    ok = all(
        r is not None and r.msg is not None and r.msg.kind == "STATUS" and seq_of(r.msg) == seq
        for r in replies
    )
    return verdict("retry_status", ok, ", ".join(_text(r) for r in replies))


def poll_status(link: Link, n: int) -> list[tuple[int, Received | None, float]]:
    """``n`` STATUS round trips: (seq, reply, round trip s)."""
    return [link.ask("STATUS") for _ in range(n)]


def check_seq(polls: list[tuple[int, Received | None, float]]) -> Check:
    """Every reply repeats its command's seq."""
    bad = [(s, _text(r)) for s, r, _ in polls if r is None or r.msg is None or seq_of(r.msg) != s]
    value = f"{len(polls) - len(bad)}/{len(polls)} replies with their command's seq"
    return verdict("seq_echo", not bad, value, f"first wrong: seq {bad[0][0]} got {bad[0][1]}" if bad else "")


def check_latency(
    polls: list[tuple[int, Received | None, float]],
    baudrate: int,
    timeout: float,
    budget_s: float = rp.REPLY_BUDGET_S,
) -> Check:
    """STATUS round trips against the reply budget plus both lines' time on the wire and a USB-serial
    adapter's latency: judged on the median (the host's own scheduling adds to some round trips what the
    base did not cause; a rare late reply is the host's timeout's business), and no reply later than the
    host's timeout. The 90th percentile and the maximum are reported."""
    rtts = sorted(rtt for _, _, rtt in polls)
    if not rtts:
        return verdict("latency", False, "no round trip")
    allowed = budget_s + wire_s(8 + 70, baudrate) + rp.USB_LATENCY_S
    p50, p90, worst = statistics.median(rtts), rtts[int(0.9 * (len(rtts) - 1))], rtts[-1]
    value = f"p50 {ms(p50)}, p90 {ms(p90)}, max {ms(worst)} of {len(rtts)}; allowed p50 {ms(allowed)}"
    return verdict(
        "latency",
        p50 <= allowed and worst <= timeout,
        value,
        "" if worst <= timeout else f"a reply later than the host's timeout {ms(timeout)}",
    )


@dataclass(frozen=True)
class ClockReadings:
    """The base's clock as the kit saw it: ``polled`` (host write time, host read time, t_us) of STATUS
    polls, the base's stamp taken between the two; ``all_t_us``, every STATUS ``t_us`` of the run, in
    order."""

    polled: list[tuple[float, float, int]]
    all_t_us: list[int]


def status_t_us(link: Link, seconds: float) -> ClockReadings:
    """STATUS polled for ``seconds`` (every 20 ms), and every STATUS ``t_us`` read in the run so far: a
    wrap anywhere in the run shows."""
    polled = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        _, got, rtt = link.ask("STATUS")
        if got is not None and (t_us := _t_us(got)) is not None:
            polled.append((got.t - rtt, got.t, t_us))
        link.quiet(0.02)  # reading, not sleeping: a STOP owed meanwhile goes out within a read slice
    return ClockReadings(polled, [t for r in link.log if (t := _t_us(r)) is not None])


def _t_us(r: Received) -> int | None:
    if r.msg is None or r.msg.kind != "STATUS" or len(r.msg.fields) <= rp.STATUS_V1_FIELDS:
        return None
    try:
        return rp.device_us(r.msg, rp.STATUS_V1_FIELDS)
    except rp.ProtocolError:
        return None


def check_clock(readings: ClockReadings) -> list[Check]:
    """``t_us`` never goes back and counts µs at the host's rate; ``t_us_width``: it is wider than 32 bits.
    A value at or above 2³² proves the width; below, it cannot be shown yet, so that check is skipped with
    its reason (run again after 72 min of uptime) rather than passed or failed on no evidence.
    The rate is bounded, not estimated: each stamp was taken between its poll's write and read, so the
    base's interval from the first poll to the last lies between (write_last - read_first) and
    (read_last - write_first) of the host's, widened by CLOCK_PPM (two crystals): the host's load only
    widens the bounds, it never fails a good base."""
    polled, all_t = readings.polled, readings.all_t_us
    if len(polled) < 2:
        return [verdict("t_us", False, f"{len(polled)} STATUS with t_us", "a base with CLOCK sends t_us")]
    back = [b - a for a, b in zip(all_t, all_t[1:]) if b < a]
    value = f"{len(all_t)} readings, last {all_t[-1]} µs"
    if back:
        return [verdict("t_us", False, value, f"went back by {-min(back)} µs (a wrap or a restart)")]
    (w0, r0, u0), (w1, r1, u1) = polled[0], polled[-1]
    device_s = (u1 - u0) / 1e6
    low, high = (w1 - r0) * (1 - CLOCK_PPM * 1e-6), (r1 - w0) * (1 + CLOCK_PPM * 1e-6)
    value += f"; {device_s:.4f} s of its clock in {low:.4f}..{high:.4f} s of the host's"
    if not low <= device_s <= high:
        return [verdict("t_us", False, value, "not counting µs at the host's rate")]
    rate = verdict("t_us", True, value, "never back, at the host's rate")
    top = f"largest {max(all_t)} µs"
    if max(all_t) < 2**32:
        return [rate, Check("t_us_width", "skip", top, "below 2^32: the width shows only after 71.6 min "
                            "of uptime; run again then")]
    return [rate, verdict("t_us_width", True, top, "above 2^32: wider than 32 bits")]


def check_streams(link: Link, caps: list[str], rate_hz: float = 20.0, seconds: float = 1.0) -> list[Check]:
    """STATE at ``rate_hz``: samples at that rate of the base's clock, t_us increasing; a rate out of range
    NAK RANGE; STATE 0 stops them."""
    if rp.CAP_STATE not in caps:
        return [Check("streams", "skip", "no STATE capability")]
    _, ack, _ = link.ask("STATE", rp.num(rate_hz))
    start = time.monotonic()
    link.quiet(seconds)
    samples = [r for r in link.log if r.t >= start and r.msg is not None and r.msg.kind == "STATE"]
    t_us = []
    for r in samples:
        try:
            t_us.append(rp.StateSample.decode(r.msg).t_us)  # type: ignore[arg-type]
        except rp.ProtocolError:
            pass
    _, nak, _ = link.ask("STATE", 500)
    _, off, _ = link.ask("STATE", 0)
    link.quiet(0.1)
    stopped_at = time.monotonic()
    link.quiet(0.2)
    late = [r for r in link.log if r.t >= stopped_at and r.msg is not None and r.msg.kind in rp.STREAMS]
    span = (t_us[-1] - t_us[0]) / 1e6 if len(t_us) > 1 else 0.0
    measured = (len(t_us) - 1) / span if span > 0 else 0.0
    problems = [
        p
        for p, bad in (
            (
                f"STATE {rp.num(rate_hz)} answered {_text(ack)}",
                ack is None or ack.msg is None or ack.msg.kind != "ACK",
            ),
            ("sample t_us not increasing", any(b <= a for a, b in zip(t_us, t_us[1:]))),
            (
                f"rate {measured:.1f} Hz of its clock, asked {rp.num(rate_hz)}",
                abs(measured - rate_hz) > 0.1 * rate_hz,
            ),
            (
                f"STATE 500 answered {_text(nak)}",
                nak is None or nak.msg is None or nak.msg.fields[1:2] != ("RANGE",),
            ),
            (f"STATE 0 answered {_text(off)}", off is None or off.msg is None or off.msg.kind != "ACK"),
            (f"{len(late)} samples after STATE 0", bool(late)),
        )
        if bad
    ]
    value = f"{len(t_us)} STATE samples in {seconds:.1f} s, {measured:.1f} Hz of the base's clock"
    return [verdict("streams", not problems, value, "; ".join(problems))]


def check_framing(link: Link, since: int = 0) -> Check:
    """Every line the base sent (from log entry ``since`` on) was a well-formed frame, checksum right."""
    lines = link.log[since:]
    bad = link.bad_lines(since)
    value = f"{len(lines) - len(bad)}/{len(lines)} lines well formed"
    return verdict(
        "framing", not bad, value, f"first bad: {bad[0].raw[:60]!r} ({bad[0].error[:60]})" if bad else ""
    )
