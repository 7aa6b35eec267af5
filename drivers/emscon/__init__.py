"""Leica emScon TPI (binary protocol over TCP, port 700) for the AT901 laser tracker.

``codec`` encodes/decodes packets, ``framer`` cuts the byte stream, ``client`` runs
one command at a time over a socket, ``adapter`` is the daemon's ``Tracker``.
"""
