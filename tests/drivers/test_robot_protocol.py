"""The robot line codec on its own: checksum, framing, parsing, malformed input."""
from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers import robot_protocol as rp


def test_checksum_matches_a_published_nmea_sentence() -> None:
    # the GPGGA example sentence found in NMEA 0183 tutorials carries checksum 47
    body = "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"
    assert rp.checksum(body) == "47"
    assert rp.decode(f"${body}*47\r\n".encode()).kind == "GPGGA"


def test_encode_frames_and_formats_numbers() -> None:
    line = rp.encode("MOVE", 12, 200.0, 50)
    assert line.startswith(b"$MOVE,12,200,50*") and line.endswith(b"\r\n")
    body = b"MOVE,12,200,50"
    cs = 0
    for b in body:
        cs ^= b
    assert line == b"$" + body + b"*" + f"{cs:02X}".encode() + b"\r\n"
    assert rp.encode("STATUS", 3, None, -0.0) == rp.encode("STATUS", 3, "", "0")
    assert rp.num(1.23456789) == "1.234568"
    assert rp.num(-2.5, 4) == "-2.5"
    assert rp.num(-1e-9) == "0"


def test_decode_round_trip_and_field_access() -> None:
    msg = rp.decode(rp.encode("STATUS", 7, "IDLE", 1.5, -2.25, 90.0, None, None, 24.9, ""))
    assert msg.kind == "STATUS" and msg.seq() == 7
    assert msg.field(1, "state") == "IDLE"
    assert msg.number(2, "x") == 1.5 and msg.number(3, "y") == -2.25
    assert msg.optional_number(5, "roll") is None
    assert msg.optional_number(7, "battery") == 24.9
    assert msg.optional_number(20, "absent") is None
    # lower-case hex checksums are accepted on input
    line = rp.encode("STOP", 8)
    assert line.endswith(b"*0C\r\n")
    assert rp.decode(line.replace(b"*0C", b"*0c")).kind == "STOP"


@pytest.mark.parametrize("line, kind, fragment", [
    (b"hello world", "garbage", "not a '$BODY*HH' frame"),
    (b"$MOVE,1,200,50", "garbage", "frame"),
    (b"$MOVE,1,200,50*4", "garbage", "frame"),
    (b"$MOVE,1,200,50*ZZ", "garbage", "'ZZ'"),
    (b"$MO$VE,1*00", "garbage", "framing character"),
    (b"$MOVE,1,\xff*00", "garbage", "non-ASCII"),
    (b"$MOVE,1\x07*00", "garbage", "control"),
    (b"$" + b"A" * 300 + b"*00", "garbage", "exceeds"),
    (b"$MOVE,1,200,50*00", "checksum", "computed"),
    (b"$move,1*" + rp.checksum("move,1").encode(), "syntax", "'move'"),
])
def test_malformed_lines_raise_a_clear_error(line: bytes, kind: str, fragment: str) -> None:
    with pytest.raises(rp.ProtocolError) as info:
        rp.decode(line)
    assert info.value.kind == kind
    assert fragment in str(info.value)


def test_bad_fields_name_the_value() -> None:
    msg = rp.decode(rp.encode("MOVE", 4, "fast", "nan"))
    with pytest.raises(rp.ProtocolError, match="distance_mm='fast' is not a number"):
        msg.number(1, "distance_mm")
    with pytest.raises(rp.ProtocolError, match="speed='nan' is not finite"):
        msg.number(2, "speed")
    with pytest.raises(rp.ProtocolError, match=r"missing field 4 \(x\)"):
        msg.field(3, "x")
    with pytest.raises(rp.ProtocolError, match="seq='0'"):
        rp.decode(rp.encode("ACK", 0)).seq()
    with pytest.raises(rp.ProtocolError, match="seq='x1'"):
        rp.decode(rp.encode("ACK", "x1")).seq()
    assert rp.decode(rp.encode("NAK", None, "CHECKSUM")).seq() is None


def test_encode_refuses_fields_that_would_misparse() -> None:
    for bad in ("a,b", "a*b", "$", "line\n", "é"):
        with pytest.raises(ValueError, match="framing or non-ASCII"):
            rp.encode("NAK", 1, bad)
    with pytest.raises(ValueError, match="non-finite"):
        rp.encode("MOVE", 1, math.inf, 1.0)
    with pytest.raises(ValueError, match="exceeds"):
        rp.encode("NAK", 1, "x" * 200)
    assert rp.text_field("bad, text*with$stuff\n") == "bad  text with stuff "


def test_line_splitter_reassembles_and_drops_overlong_runs() -> None:
    sp = rp.LineSplitter()
    assert sp.feed(b"$A,1*") == []
    assert sp.feed(b"00\r\n$B,2*00\n$C") == [b"$A,1*00", b"$B,2*00"]
    assert sp.feed(b"x" * (rp.MAX_LINE + 10)) == []
    assert sp.overflows == 1
    # the tail of the over-long run is dropped, the next line survives
    assert sp.feed(b"tail\n$D,3*00\n") == [b"$D,3*00"]
    assert sp.overflows == 1


def test_sequence_numbers_wrap_and_skip_zero() -> None:
    assert rp.next_seq(1) == 2
    assert rp.next_seq(rp.SEQ_MAX) == 1


_field = st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126,
                                        blacklist_characters="$*,"), max_size=12)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(kind=st.sampled_from(rp.COMMANDS + rp.REPLIES + rp.EVENTS), fields=st.lists(_field, max_size=8))
def test_any_encodable_message_decodes_to_itself(kind: str, fields: list[str]) -> None:
    msg = rp.decode(rp.encode(kind, *fields))
    assert msg == rp.Message(kind, tuple(fields))


@settings(max_examples=300, deadline=None, derandomize=True)
@given(data=st.binary(max_size=200))
def test_random_bytes_never_crash_the_decoder(data: bytes) -> None:
    try:
        msg = rp.decode(data)
    except rp.ProtocolError as exc:
        assert exc.kind in ("garbage", "checksum", "syntax")
    else:
        assert msg.kind.isupper()
