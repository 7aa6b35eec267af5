"""ritad as a real process killed with SIGKILL while it writes captures: no torn files.

A thread hammers ``capture`` (the tracker locked onto the robot first) and the
daemon is SIGKILLed, four times on the same data directory: twice at a seeded random
moment and twice the instant a temp file shows up (so the kill lands inside a
write). Afterwards every JSON file loads, every PNG decodes, every manifest entry
exists, no temp file is listed anywhere, and every capture that was acknowledged
is in its manifest.
"""
from __future__ import annotations

import json
import os
import random
import signal
import threading
import time
from pathlib import Path
from typing import Any

import cv2

from daemon.bus.client import Client
from fakes.operator import lock_on_robot
from daemon.bus.protocol import CommandError
from fakes.launch import RitadProcess, spawn_ritad
from tools.harness.config import ipc_command, ritad_toml

CAMERA_SIZE = (160, 120)


def write_config(tmp: Path, data: Path) -> tuple[Path, str]:
    """A TOML config for a sim ritad with small camera images; returns (path, command endpoint)."""
    rt = tmp / "rt"
    rt.mkdir(exist_ok=True)
    path = tmp / "ritad.toml"
    path.write_text(ritad_toml(ipc_dir=rt, data=data, devices={"camera": f"sim:?size={CAMERA_SIZE[0]}x{CAMERA_SIZE[1]}"},
                               seed=5))
    return path, ipc_command(rt)


def Ritad(tmp: Path, config: Path, watchdog_usec: int | None = None) -> RitadProcess:  # noqa: N802
    """ritad --config CONFIG with a private NOTIFY_SOCKET (fakes/launch.py); not yet waited for."""
    return spawn_ritad(["--config", str(config)], tmp=tmp,
                       env={"WATCHDOG_USEC": str(watchdog_usec)} if watchdog_usec else None)


def hammer(endpoint: str, tag: str, acked: list[str], stop: threading.Event) -> None:
    """Capture as fast as the daemon allows until it stops answering."""
    with Client(endpoint, timeout=3) as c:
        i = 0
        while not stop.is_set():
            try:
                acked.append(c.call("capture", label=f"{tag}-{i}", dataset="hammer")["path"])
            except CommandError:
                return  # the daemon was killed (ClientTimeout) or refused: stop hammering
            i += 1


def wait_for_temp_file(folder: Path, timeout: float) -> None:
    """Return the moment a temp file (a write in progress) appears in ``folder``."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            if any(e.name.endswith(".tmp") for e in os.scandir(folder)):
                return
        except FileNotFoundError:
            pass  # the dataset folder is made by the first capture
    raise AssertionError(f"no write seen in {folder} within {timeout} s")


def check_data_dir(data: Path) -> dict[str, Any]:
    """Every file parses, every manifest entry exists and is no temp file; returns the figures."""
    jsons = sorted(data.rglob("*.json"))
    for p in jsons:
        json.loads(p.read_text())  # raises on a torn file
    pngs = sorted(data.rglob("*.png"))
    for p in pngs:
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        assert img is not None and img.shape == CAMERA_SIZE[::-1], p
    listed: set[Path] = set()
    for manifest in data.rglob("dataset.json"):
        for e in json.loads(manifest.read_text())["entries"]:
            for key in ("json", "image"):
                f = manifest.parent / e[key]
                assert f.is_file() and not f.name.endswith(".tmp"), (manifest, e)
                listed.add(f)
            assert json.loads((manifest.parent / e["json"]).read_text())["image_file"] == e["image"]
    temps = [p for p in data.rglob("*") if p.name.endswith(".tmp")]
    assert not listed & set(temps)
    return {"json": len(jsons), "png": len(pngs), "listed": len(listed) // 2, "tmp_left": len(temps),
            "listed_paths": listed}


def test_sigkill_while_capturing(tmp_path: Path) -> None:
    rng = random.Random(20261121)
    data = tmp_path / "data"
    config, endpoint = write_config(tmp_path, data)
    acked: list[str] = []
    t0 = time.monotonic()
    targeted = 0
    for rnd, how in enumerate(["random", "mid-write", "random", "mid-write"]):
        ritad = Ritad(tmp_path, config)
        try:
            ritad.wait_notify_ready()
            with Client(endpoint, timeout=10) as c:
                c.wait_ready()
                lock_on_robot(c)
            n_before = len(acked)
            stop = threading.Event()
            t = threading.Thread(target=hammer, args=(endpoint, f"r{rnd}", acked, stop), daemon=True)
            t.start()
            if how == "random":
                time.sleep(rng.uniform(0.5, 1.5))
            else:
                wait_for_temp_file(data / "datasets" / "hammer", 10)
                targeted += 1
            ritad.proc.send_signal(signal.SIGKILL)
            assert ritad.proc.wait(10) == -signal.SIGKILL
            stop.set()
            t.join(10)
            assert len(acked) > n_before or how == "mid-write", "no capture was acknowledged before the kill"
        finally:
            ritad.kill()
    figures = check_data_dir(data)
    missing = [p for p in acked if Path(p) not in figures["listed_paths"]]
    assert not missing, f"acknowledged captures not in a manifest: {missing}"
    assert targeted == 2
    print(f"\nSIGKILL x4 (2 mid-write) in {time.monotonic() - t0:.1f} s: {len(acked)} captures acknowledged; "
          f"{figures['json']} json, {figures['png']} png, {figures['listed']} manifest entries, "
          f"{figures['tmp_left']} temp files left behind")
