"""The sample lines' short path (drivers/robot_stream.py ``parse_sample``) reads exactly what the
general path (``rp.decode`` and the samples' ``decode``) reads, and refuses everything it refuses."""
from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from drivers import robot_protocol as rp
from drivers.robot_stream import StreamBatcher, parse_sample


def general(raw: bytes) -> tuple[str, tuple[Any, ...]] | None:
    """What the driver's general path makes of a line: a sample's kind and values, or None."""
    try:
        msg = rp.decode(raw)
        if msg.kind == "STATE":
            s = rp.StateSample.decode(msg)
            return "STATE", (s.t_us, s.x_mm, s.y_mm, s.heading_deg, s.v_left_mm_s, s.v_right_mm_s)
        if msg.kind == "INCL":
            i = rp.InclSample.decode(msg)
            return "INCL", (i.t_us, i.roll_deg, i.pitch_deg)
    except rp.ProtocolError:
        return None
    return None


def framed(body: str, lower: bool = False) -> bytes:
    cs = rp.checksum(body)
    return f"${body}*{cs.lower() if lower else cs}".encode()


VALID = [
    rp.StateSample(123456789, 12.3456, -3.21, 45.123456, 100.5, -99.5).encode().rstrip(b"\r\n"),
    rp.InclSample(0, 0.012345, -0.023456).encode().rstrip(b"\r\n"),
    rp.InclSample(9_999_999_999_999_999_999, 1e-6, -179.999999).encode().rstrip(b"\r\n"),
    framed("INCL,17,1e-3,-2E2"),  # what float() reads, both paths read
    framed("INCL,17, 1.5 ,2_0"),
    framed("STATE,5,1,2,3,4,5,extra,fields"),  # fields past the sample's are ignored by both
    framed("INCL,17,0.5,0.25", lower=True),  # a lower-case checksum is accepted by rp.decode
]

REFUSED = [
    framed("INCL,17,0.5"),  # a field missing
    framed("STATE,5,1,2,3,4"),
    framed("INCL,-17,0.5,0.25"),  # t_us not a non-negative integer
    framed("INCL,1.5,0.5,0.25"),
    framed("INCL,12345678901234567890,0.5,0.25"),  # 20 digits
    framed("INCL,17,nan,0.25"),
    framed("INCL,17,inf,0.25"),
    framed("INCL,17,x,0.25"),
    f"$INCL,17,0.5,0.25*{int(rp.checksum('INCL,17,0.5,0.25'), 16) ^ 1:02X}".encode(),  # wrong checksum
    b"$INCL,17,0.5,0.25*ZZ",
    b"$INCL,17,0.5,0.25",  # no checksum
    b"INCL,17,0.5,0.25*00",  # no $
    framed("INCL,17,0.5$,0.25"),
    framed("INCL,17,0.5*,0.25"),
    framed("INCL,17,\t0.5,0.25"),  # a control character
    framed("INCL,17,0.5,0.25").replace(b"0.5", "0.\u00b5".encode()),  # not ASCII
    framed("INCL,17," + "1" * 150 + ",0.25"),  # longer than MAX_LINE
    framed("STATUS,3,IDLE,0,0,0"),  # not a sample: the general path's
    framed("DONE,3,OK,0,0,0"),
    framed("INCLX,17,0.5,0.25"),
    framed("STATEX,17,0.5,0.25,1,2,3"),
    b"", b"*", b"$*", b"$INCL*00", b"   ",
]


@pytest.mark.parametrize("raw", VALID)
def test_valid_samples_read_as_the_general_path_reads_them(raw: bytes) -> None:
    got = parse_sample(raw)
    assert got is not None
    assert got == general(raw)
    assert [type(v) for v in got[1]] == [int] + [float] * (len(got[1]) - 1)


@pytest.mark.parametrize("raw", REFUSED)
def test_anything_else_is_left_to_the_general_path(raw: bytes) -> None:
    assert parse_sample(raw) is None


def test_mutated_lines_never_read_differently() -> None:
    """Seeded byte flips, cuts and insertions of valid lines: the short path takes a line only when the
    general path reads the same sample from it."""
    rng = np.random.default_rng(7)
    taken = refused = 0
    for i in range(4000):
        line = bytearray(VALID[i % len(VALID)])
        for _ in range(int(rng.integers(1, 3))):
            at = int(rng.integers(0, len(line)))
            op = int(rng.integers(0, 3))
            if op == 0:
                line[at] = int(rng.choice(list(b"0123456789.,-+*$eE \x00\xff")))
            elif op == 1:
                del line[at]
            else:
                line.insert(at, int(rng.choice(list(b"0123456789.,"))))
        raw = bytes(line)
        fast, slow = parse_sample(raw), general(raw)
        assert fast is None or fast == slow, raw
        taken += fast is not None
        refused += slow is None
    assert taken > 0 and refused > 0  # both outcomes were exercised


def test_batcher_take_and_add_make_the_same_batches() -> None:
    lines = [VALID[0], VALID[1], VALID[2], VALID[5]]
    got: dict[str, list[Any]] = {"take": [], "add": []}
    fast, slow = StreamBatcher(lambda t, p: got["take"].append((t, p))), \
        StreamBatcher(lambda t, p: got["add"].append((t, p)))
    for n, raw in enumerate(lines):
        assert fast.take(raw, 1000 + n)
        slow.add(rp.decode(raw), 1000 + n)
    assert not fast.take(REFUSED[0], 9)
    fast.flush(force=True)
    slow.flush(force=True)
    assert got["take"] == got["add"] and len(got["take"]) == 2
    assert fast.counters == slow.counters == {"state_samples": 2, "incl_samples": 2}
