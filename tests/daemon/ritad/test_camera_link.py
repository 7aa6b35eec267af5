"""ritad's camera status shows the GigE transport, the link statistics and the PTP state (sim camera)."""
from __future__ import annotations

from pathlib import Path

import pytest

from daemon.ritad import config
from tests.ritad_up import SMALL_CAMERA, ritad_in_process

pytestmark = pytest.mark.timeout(90)


def test_camera_status_shows_transport_link_and_ptp(tmp_path: Path) -> None:
    def configure(cfg: config.Config) -> None:
        cfg.camera.packet_size = 9000
        cfg.camera.packet_resend = True
        cfg.camera.stream_buffers = 6
        cfg.camera.chunks = True

    # a NIC without jumbo frames: every 9000-byte packet is lost, so every frame is incomplete
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", configure=configure,
                          camera=SMALL_CAMERA + "&path_mtu=1500") as (_, c):
        headers = [c.call("camera.capture", save=False)["header"] for _ in range(2)]
        st = c.call("camera.status")
    assert st["applied"]["GevSCPSPacketSize"] == 9000 and st["applied"]["StreamBufferCount"] == 6
    assert st["applied"]["StreamPacketResendEnable"] is True
    assert st["ptp"] == {"available": False}
    assert st["link"]["incomplete_frames"] == 2 and st["link"]["lost_packets"] > 0
    assert [h["incomplete_count"] for h in headers] == [1, 2]
    assert all("chunk_exposure_us" in h for h in headers)
