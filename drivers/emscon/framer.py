"""Streaming framer: cuts a TCP byte stream into emScon packets by ``lPacketSize``."""
from __future__ import annotations

import struct

from drivers.emscon.codec import MAX_PACKET, MIN_PACKET, TO_CLIENT, TO_SERVER, Packet, ProtocolError, decode

_SIZE = struct.Struct("<i")


class Framer:
    """Cuts a TCP byte stream into packets by ``lPacketSize``.

    ``feed`` accepts chunks split or merged anywhere and returns the whole packets
    completed so far. After a :class:`ProtocolError` the stream cannot be resynchronised,
    so every later ``feed`` raises the same error; the error's ``packets`` holds the whole
    packets that came before the bad bytes in that chunk.
    """

    def __init__(self, direction: str, max_packet: int = MAX_PACKET) -> None:
        if direction not in (TO_SERVER, TO_CLIENT):
            raise ValueError(f"direction must be {TO_SERVER!r} or {TO_CLIENT!r}, not {direction!r}")
        self.direction = direction
        self.max_packet = max_packet
        self._buf = bytearray()
        self._error: ProtocolError | None = None

    @property
    def pending(self) -> int:
        """Bytes received but not yet part of a whole packet."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Packet]:
        if self._error is not None:
            raise self._error
        buf = self._buf
        buf += data
        out: list[Packet] = []
        pos, end = 0, len(buf)
        try:
            while end - pos >= 4:
                (size,) = _SIZE.unpack_from(buf, pos)
                if size < MIN_PACKET or size > self.max_packet:
                    raise ProtocolError(f"lPacketSize {size} outside [{MIN_PACKET}, {self.max_packet}]")
                if end - pos < size:
                    break
                out.append(decode(bytes(buf[pos:pos + size]), self.direction))
                pos += size
        except ProtocolError as exc:
            self._error = exc
            exc.packets = out  # whole packets before the bad one are good
            raise
        finally:
            del buf[:pos]
        return out
