"""A colour sim camera through ritad: the pixel format travels in the frame header, the capture
and the dataset, and the folder validates."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from daemon.bus.datasets import validate_folder
from daemon.compute.images import grey_loader, read_image
from tests.ritad_up import ritad_in_process

pytestmark = pytest.mark.timeout(120)


@pytest.mark.parametrize("fmt,dtype", [("BayerRG12p", "<u2")])  # RGB8: tests/daemon/bus/test_dataset_formats.py
def test_capture_keeps_the_pixel_format_end_to_end(tmp_path: Path, fmt: str, dtype: str) -> None:
    def colour(cfg) -> None:
        cfg.camera.pixel_format = fmt

    with ritad_in_process(tmp_path / "rt", tmp_path / "data", configure=colour) as (_, c):
        shot, extra = c.call_raw("camera.capture", {"pixels": True, "save": False}, timeout=60)
        h = shot["header"]
        assert h["pixel_format"] == fmt and h["dtype"] == dtype
        assert list(np.frombuffer(extra[0].buffer, np.dtype(dtype)).shape) == [int(np.prod(h["shape"]))]
        path = Path(c.call("camera.capture", label="colour", save=True, timeout=60)["path"])
    assert validate_folder(path.parent) == []
    img, got = read_image(path.parent, path.with_suffix(".png").name)
    assert got == fmt and list(img.shape) == h["shape"] and img.dtype == np.dtype(dtype)
    grey = grey_loader(path.parent)(path.with_suffix(".png").name)
    assert grey.dtype == np.uint8 and grey.shape == tuple(h["shape"][:2])
