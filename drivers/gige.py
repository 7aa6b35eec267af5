"""Facts of the GigE Vision link that the GenICam camera adapter and its fake share."""
from __future__ import annotations

#: the smallest GigE packet size accepted: the IPv4 datagram size every host must be able to receive
MIN_PACKET_BYTES = 576
#: 1000BASE-T's line rate, bytes/s: what a GigE camera sends at without a throughput limit
GIGE_LINE_BYTES_S = 125_000_000
