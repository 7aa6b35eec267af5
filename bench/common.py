"""The benchmarks' one harness: machine facts, percentiles, /proc readings, ritad on the fakes
(``fakes.launch``) from the one config template (``tools.harness.config``), and helper processes
that subscribe, count, and report JSON when told to stop; a full-size referencing dataset folder."""
from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fakes.launch import RitadProcess, start_ritad  # noqa: E402  (the shared "ritad up" helper)
from tools.harness.config import NO_DEVICES, ritad_toml  # noqa: E402  (the shared config template)

CLK_TCK = os.sysconf("SC_CLK_TCK")


def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"{platform.system()} {platform.release()}, {time.strftime('%Y-%m-%d', time.gmtime())}")


def pct(values: list[float], q: float) -> float:
    v = sorted(values)
    return v[min(len(v) - 1, int(round(q / 100 * (len(v) - 1))))] if v else float("nan")


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process (all its threads), in seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # fields 14 and 15 of stat(5)


def vm_kib(pid: int, key: str) -> int:
    """A ``Vm*`` line of /proc/<pid>/status (VmRSS, VmHWM) in KiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def pick(endpoints: list[str], scheme: str) -> str:
    """The first endpoint of ``scheme`` (``ipc://``, ``tcp://``)."""
    return next(e for e in endpoints if e.startswith(scheme))


def spawn(script: str, *args: str) -> subprocess.Popen:
    """Start a helper process (``bench/<script> ARGS``) and wait until it prints ``subscribed``."""
    proc = subprocess.Popen([sys.executable, str(ROOT / "bench" / script), *args], cwd=ROOT,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline().strip()
    if line != "subscribed":
        proc.kill()
        raise RuntimeError(f"helper {script} {args} did not start: {line!r}")
    time.sleep(0.5)  # let the subscription reach the daemon's PUB socket
    return proc


def finish(proc: subprocess.Popen, timeout: float = 60) -> dict[str, Any]:
    """Tell a helper process to stop and return its JSON result."""
    out, _ = proc.communicate("stop\n", timeout=timeout)
    lines = out.strip().splitlines()
    if proc.returncode or not lines:
        raise RuntimeError(f"helper exited with {proc.returncode}: {out[-500:]!r}")
    return json.loads(lines[-1])


def serve_subscriber(sub: Any, add: Callable[[list[Any], int], None], result: Callable[[], dict[str, Any]],
                     stalled: bool, linger_s: float) -> None:
    """The helper side of :func:`spawn`: print ``subscribed``, hand each message's frames and receive
    time (ns) to ``add`` (unless ``stalled``) until stdin closes plus ``linger_s``, print ``result()``."""
    import zmq

    print("subscribed", flush=True)
    poller = zmq.Poller()
    poller.register(sub.sock, zmq.POLLIN)
    poller.register(sys.stdin.fileno(), zmq.POLLIN)
    stop_at = None
    while stop_at is None or time.monotonic() < stop_at:
        events = dict(poller.poll(200))
        if sys.stdin.fileno() in events and stop_at is None:
            os.read(sys.stdin.fileno(), 4096)  # the parent wrote or closed stdin: finish soon
            stop_at = time.monotonic() + linger_s
            poller.unregister(sys.stdin.fileno())
        if sub.sock in events and not stalled:
            for _ in range(1000):  # drain what is there before polling stdin again
                try:
                    frames = sub.sock.recv_multipart(zmq.NOBLOCK, copy=False)
                except zmq.Again:
                    break
                add(frames, time.monotonic_ns())
    print(json.dumps(result()), flush=True)
    sub.close()



#: the camera's full image size (width, height)
FULL = (4024, 3036)


def write_referencing_folder(root: Path, size: tuple[int, int] = FULL, seed: int = 5) -> None:
    """A referencing dataset as the worker writes it, from one simulated visit with a rendered image."""
    import json

    import cv2

    from fakes.simulate import SimConfig, Simulation
    from fakes.world import World, WorldParams

    world = World(WorldParams(seed=seed))
    sim = Simulation(world, SimConfig(seed=seed, render=True, size=size, repetitions=1, directions=1))
    obs = sim.calibration()
    root.mkdir(parents=True)
    cv2.imwrite(str(root / "run0.png"), obs.image)

    def point(p) -> dict:
        return {"abs_xyz": [float(v) for v in p]}
    header = {"shape": [size[1], size[0]], "dtype": "|u1"}
    state = {"schema": 1, "job": "bench", "procedure": "referencing",
             "obs": {"plate": world.plate().to_dict(), "camera_model": sim.model.to_dict(),
                     "sigma_t_mm": 0.010,
                     "nests": {n: point(p) for n, p in zip(("red", "green", "blue"), obs.abs_P_nests)},
                     "runs": [{"tag": "run0", "image": "run0.png", "header": header,
                               "P0": point(obs.abs_P_rob0), "P1": point(obs.abs_P_rob1)}]}}
    (root / "state.json").write_text(json.dumps(state))
    (root / "run0.json").write_text(json.dumps({"camera": header, "image_file": "run0.png"}))
    (root / "dataset.json").write_text(json.dumps({"schema": 1, "kind": "procedure:referencing", "meta": {},
                                                   "entries": [{"name": "run0", "json": "run0.json",
                                                                "image": "run0.png"}]}))


__all__ = ["FULL", "NO_DEVICES", "ROOT", "RitadProcess", "cpu_seconds", "finish", "machine", "pct", "pick",
           "ritad_toml", "serve_subscriber", "spawn", "start_ritad", "vm_kib", "write_referencing_folder"]
