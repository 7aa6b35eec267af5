"""One client connection of the fake emScon server, with the fault knobs.

A session reads requests through the codec's framer and runs one command at a
time: a request that arrives while a command runs is answered ServerBusy at once.
Every packet it writes passes the fault knobs (drop, garbage, byte-wise split).
"""
from __future__ import annotations

import asyncio
import struct
from dataclasses import dataclass, field
from typing import Protocol

from drivers.emscon.codec import Packet, ProtocolError, encode_answer
from drivers.emscon.enums import ES_ResultStatus as RS
from drivers.emscon.framer import TO_SERVER, Framer

@dataclass
class Faults:
    """Fault knobs; change them at any time (they apply to the next packet/command)."""

    drop_after: int = 0  # close the connection after this many packets sent (0 = never)
    delay_ms: float = 0.0  # extra delay before every answer
    split: bool = False  # write every packet one byte at a time
    garbage_after: int = 0  # after this many packets sent, write garbage instead (0 = never)
    result_first: bool = False  # stationary result before the StartMeasurement answer
    fail: dict[int, int] = field(default_factory=dict)  # command -> status to answer with
    #: command -> an OutOfRangeOK status answered in place of AllOK, the command taking effect (the
    #: header's ES_RS_Parameter<k>OutOfRangeOK: out of range, yet accepted)
    ok: dict[int, int] = field(default_factory=dict)


class Dropped(Exception):
    """The fault knob closed the connection."""


class Server(Protocol):
    """What a session needs of the server that accepted it (FakeTrackerServer)."""

    faults: Faults

    async def execute(self, session: "Session", req: Packet) -> None: ...


class Session:
    """One client connection."""

    def __init__(self, server: Server, reader: asyncio.StreamReader,
                 writer: asyncio.StreamWriter) -> None:
        self.server, self.reader, self.writer = server, reader, writer
        self.sent = 0
        self.task: asyncio.Task[None] | None = None  # the command in progress
        self.stream: asyncio.Task[None] | None = None
        self.closed = False

    async def send(self, data: bytes) -> None:
        f = self.server.faults
        if self.closed:
            raise Dropped()
        if f.garbage_after and self.sent >= f.garbage_after:
            data = b"\xff\xff\xff\x7f" + b"garbage!" * 2  # lPacketSize 2 GiB: no client may accept it
        if f.drop_after and self.sent >= f.drop_after:
            self.abort()
            raise Dropped()
        self.sent += 1
        if f.split:
            for i in range(len(data)):
                self.writer.write(data[i:i + 1])
                await self.writer.drain()
        else:
            self.writer.write(data)
            await self.writer.drain()

    async def send_quiet(self, data: bytes) -> None:
        """Send, ignoring a closed connection (for background events)."""
        try:
            await self.send(data)
        except (Dropped, ConnectionError, RuntimeError):
            pass

    def abort(self) -> None:
        if not self.closed:
            self.closed = True
            for t in (self.task, self.stream):
                if t is not None and t is not asyncio.current_task():
                    t.cancel()
            self.writer.transport.abort()

    async def run(self) -> None:
        framer = Framer(TO_SERVER)
        try:
            while not self.closed:
                data = await self.reader.read(65536)
                if not data:
                    break
                for req in framer.feed(data):
                    self.on_request(req)
        except (ProtocolError, ConnectionError):
            pass  # a garbled request stream cannot be resynchronised: hang up like the real server
        finally:
            self.abort()

    def on_request(self, req: Packet) -> None:
        if self.task is not None and not self.task.done():
            asyncio.ensure_future(self.send_quiet(encode_answer(req.command or 0, RS.ServerBusy)))
            return
        self.task = asyncio.ensure_future(self.execute(req))

    async def execute(self, req: Packet) -> None:
        try:
            await self.server.execute(self, req)
        except (Dropped, ConnectionError, RuntimeError):
            self.abort()


def bare_answer(cmd: int, status: int) -> bytes:
    """A 16-byte BasicCommandRT for a command number the codec does not know."""
    return struct.pack("<iiii", 16, 0, cmd, status)
