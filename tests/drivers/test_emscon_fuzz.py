"""Property-based fuzzing of the emScon decoder and framer: only ProtocolError may escape."""
from __future__ import annotations

import struct

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.emscon.codec import (COMMANDS, MEAS_VALUE, TO_CLIENT, TO_SERVER, ProtocolError, decode,
                                  encode_answer, encode_error, encode_request, encode_result,
                                  encode_status_change)
from drivers.emscon.framer import Framer

FUZZ = settings(max_examples=300, derandomize=True, deadline=None,
                suppress_health_check=[HealthCheck.too_slow])
directions = st.sampled_from([TO_CLIENT, TO_SERVER])
small_int = st.integers(-(1 << 31), (1 << 31) - 1)


def _valid_packets() -> list[bytes]:
    rec = np.zeros(3, MEAS_VALUE)
    rec["val2"] = [1.0, 2.0, 3.0]
    out = [encode_answer(c, 0) for c in COMMANDS] + [encode_request(c) for c in COMMANDS]
    out += [encode_result("single"), encode_result("single2"), encode_result("multi", 0, rec),
            encode_result("reflector_pos"), encode_error(49, 1), encode_status_change(27)]
    return out


VALID = _valid_packets()


@st.composite
def headerish(draw: st.DrawFn) -> bytes:
    """A plausible header (size, type, command/status) followed by random bytes."""
    body = draw(st.binary(max_size=300))
    size = draw(st.one_of(st.just(len(body) + 12), small_int, st.integers(0, 400)))
    dtype = draw(st.one_of(st.integers(-2, 13), small_int))
    word = draw(st.one_of(st.sampled_from([int(c) for c in COMMANDS]), small_int))
    return struct.pack("<iii", size, dtype, word) + body


@st.composite
def mutated(draw: st.DrawFn) -> bytes:
    """A valid packet, then truncated, extended or with bytes flipped."""
    raw = bytearray(draw(st.sampled_from(VALID)))
    how = draw(st.sampled_from(["truncate", "extend", "flip", "resize"]))
    if how == "truncate":
        del raw[draw(st.integers(0, len(raw))):]
    elif how == "extend":
        raw += draw(st.binary(min_size=1, max_size=100))
    elif how == "flip":
        for _ in range(draw(st.integers(1, 6))):
            i = draw(st.integers(0, len(raw) - 1))
            raw[i] = draw(st.integers(0, 255))
    else:
        struct.pack_into("<i", raw, 0, draw(st.one_of(small_int, st.integers(0, 2 * len(raw)))))
    return bytes(raw)


packets = st.one_of(st.binary(max_size=400), headerish(), mutated())


@FUZZ
@given(raw=packets, direction=directions)
def test_decode_raises_only_protocol_error(raw: bytes, direction: str) -> None:
    try:
        p = decode(raw, direction)
    except ProtocolError as exc:
        assert str(exc)  # every error says what was wrong
    else:
        assert struct.unpack_from("<i", raw)[0] == len(raw)
        p.describe()


@FUZZ
@given(chunks=st.lists(packets, max_size=8), direction=directions,
       cuts=st.lists(st.integers(1, 64), min_size=1, max_size=20))
def test_framer_raises_only_protocol_error(chunks: list[bytes], direction: str, cuts: list[int]) -> None:
    stream = b"".join(chunks)
    f = Framer(direction)
    pos, i, failed = 0, 0, False
    while pos < len(stream):
        step = cuts[i % len(cuts)]
        try:
            f.feed(stream[pos:pos + step])
        except ProtocolError:
            failed = True
            break
        pos += step
        i += 1
    if failed:  # sticky: the stream stays broken
        try:
            f.feed(b"")
        except ProtocolError:
            pass
        else:
            raise AssertionError("framer accepted input after a ProtocolError")


@FUZZ
@given(order=st.permutations(list(range(len(VALID)))), cuts=st.lists(st.integers(1, 50), min_size=1))
def test_framer_valid_stream_any_split(order: list[int], cuts: list[int]) -> None:
    """Valid packets cut anywhere come out whole, in order, each exactly once."""
    # requests and answers differ in direction: frame only the to-client ones
    to_client = [VALID[i] for i in order if _is_to_client(VALID[i])]
    stream = b"".join(to_client)
    f = Framer(TO_CLIENT)
    got: list[bytes] = []
    pos, i = 0, 0
    while pos < len(stream):
        step = cuts[i % len(cuts)]
        got += [p.describe() for p in f.feed(stream[pos:pos + step])]
        pos, i = pos + step, i + 1
    assert got == [decode(r, TO_CLIENT).describe() for r in to_client]
    assert f.pending == 0


def _is_to_client(raw: bytes) -> bool:
    try:
        decode(raw, TO_CLIENT)
        return True
    except ProtocolError:
        return False
