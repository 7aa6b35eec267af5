"""How fast a refused client is told so, against a CURVE ritad on loopback.

Goal: a key the daemon does not allow is reported as refused "within a
second" instead of after the 5 s no-answer timeout; the same for a client without keys and for a client
holding a wrong server key (the handshake dropped). tests/daemon/bus/test_curve.py asserts that each is
refused (``ClientRefused``, never the timeout's "no answer"); how soon is measured here.
Each sample is a fresh Client (new connection and handshake), as one ritactl run is.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import NO_DEVICES, machine, pct, ritad_toml, start_ritad  # noqa: E402
from daemon.bus.auth import create_keypair, load_keypair, load_public  # noqa: E402
from daemon.bus.client import Client, ClientRefused  # noqa: E402

CONFIG = ritad_toml(ipc_dir=None, tcp=True, devices=NO_DEVICES, curve=True)  # the bus alone, CURVE on tcp


def first_answer(endpoint: str, curve: dict | None, n: int) -> tuple[list[float], int]:
    """Milliseconds from a new Client's first call to its answer or refusal; and how many were refused."""
    times, refused = [], 0
    for _ in range(n):
        t = time.perf_counter()
        with Client(endpoint, timeout=5, curve=curve) as c:
            try:
                c.call("ping")
            except ClientRefused:
                refused += 1
        times.append((time.perf_counter() - t) * 1e3)
    return times, refused


def main(n: int = 50) -> None:
    print(f"# bench_refusal\n\nMachine: {machine()}\n")
    base = Path(tempfile.mkdtemp(prefix="rita-bench-refusal-"))
    create_keypair(base / "data" / "keys", "server")
    for name in ("alice", "mallory"):
        create_keypair(base / "laptop", name)
    (base / "data" / "authorized_keys").mkdir(parents=True)
    (base / "data" / "authorized_keys" / "alice.key").write_bytes(
        (base / "laptop" / "alice.key").read_bytes())
    server = load_public(base / "data" / "keys" / "server.key")
    keys = {}
    for name in ("alice", "mallory"):
        public, secret = load_keypair(base / "laptop" / f"{name}.key_secret")
        keys[name] = {"public": public, "secret": secret, "server": server}
    create_keypair(base / "other", "server")  # a server key from another robot
    wrong = {**keys["alice"], "server": load_public(base / "other" / "server.key")}
    r = start_ritad(CONFIG, tmp=base)  # data in base/data, where the keys are
    ep = r.endpoint
    try:
        time.sleep(2)
        print("| client, fresh connection each time | first answer or refusal | refused | goal |\n"
              "|---|---|---|---|")
        for label, curve, goal in (("allowed key (ping answered)", keys["alice"], "–"),
                                   ("unknown key", keys["mallory"], "≤ 1 s"),
                                   ("no keys (plaintext)", None, "≤ 1 s"),
                                   ("wrong server key", wrong, "≤ 1 s")):
            t, refused = first_answer(ep, curve, n)
            print(f"| {label}, n={n} | p50 {pct(t, 50):.1f} ms, p99 {pct(t, 99):.1f} ms, max {max(t):.1f} ms "
                  f"| {refused}/{n} | {goal} |")
    finally:
        r.stop()


if __name__ == "__main__":
    main()
