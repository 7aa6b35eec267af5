"""Leica emScon TPI (binary protocol over TCP, port 700) for the AT901 laser tracker.

``codec`` encodes/decodes packets, ``framer`` cuts the byte stream, ``client`` runs
one command at a time over a socket, ``adapter`` is the daemon's ``Tracker``.
"""
from drivers.emscon.codec import TO_CLIENT, TO_SERVER, Packet, ProtocolError, decode, encode
from drivers.emscon.framer import Framer

__all__ = ["TO_CLIENT", "TO_SERVER", "Framer", "Packet", "ProtocolError", "decode", "encode"]
