"""What the per-request role check costs: ``ping`` round trips of one open CURVE connection.

The command server looks the caller's key up in the allow-list at every request (so a
revocation or role change applies at once): one stat of the folder per request, plus a
full scan (a stat per key file) once a second and after every change. Measured with 1,
100 and 1000 allowed keys, in steady state (no change for 2.5 s), and a
forbidden command (refused before any handler) for comparison. Goal: ``ping`` p99 ≤ 5 ms,
as for every command round trip (docs/benchmarks.md, Daemon).
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import zmq  # noqa: E402

from bench.common import NO_DEVICES, machine, pct, ritad_toml, start_ritad  # noqa: E402
from daemon.bus import roles  # noqa: E402
from daemon.bus.auth import create_keypair, load_keypair, load_public  # noqa: E402
from daemon.bus.client import Client  # noqa: E402
from daemon.bus.protocol import CommandError  # noqa: E402


def round_trips(c: Client, cmd: str, n: int) -> list[float]:
    """Milliseconds per call of ``cmd`` on an open connection (errors count as answers)."""
    times = []
    for _ in range(n):
        t = time.perf_counter()
        try:
            c.call(cmd)
        except CommandError:
            pass
        times.append((time.perf_counter() - t) * 1e3)
    return times


def main(n: int = 3000) -> None:
    print(f"# bench_roles\n\nMachine: {machine()}\n")
    base = Path(tempfile.mkdtemp(prefix="rita-bench-roles-"))
    create_keypair(base / "data" / "keys", "server")
    auth = base / "data" / "authorized_keys"
    public, _ = create_keypair(base / "laptop", "vic")
    roles.write_entry(auth, "vic", load_public(public), "viewer")
    pub, sec = load_keypair(base / "laptop" / "vic.key_secret")
    curve = {"public": pub, "secret": sec, "server": load_public(base / "data" / "keys" / "server.key")}
    # data: base/data
    r = start_ritad(ritad_toml(ipc_dir=None, tcp=True, devices=NO_DEVICES, curve=True), tmp=base)
    ep = r.endpoint
    print("| allowed keys | command | round trip, one open connection | goal |\n|---|---|---|---|")
    try:
        time.sleep(2)
        allowed = 1
        for target in (1, 100, 1000):
            while allowed < target:  # more keys in the folder: more files stat'ed per request
                roles.write_entry(auth, f"k{allowed}", zmq.curve_keypair()[0], "operator")
                allowed += 1
            time.sleep(2.5)  # past the key ring's "changed too recently" window: steady state
            with Client(ep, timeout=5, curve=curve) as c:
                c.call("ping")  # handshake and first re-read of the folder outside the timing
                for cmd in ("ping", "robot.release") if target in (1, 1000) else ("ping",):
                    t = round_trips(c, cmd, n)
                    what = "`robot.release` (forbidden: viewer)" if cmd != "ping" else "`ping`"
                    print(f"| {target} | {what}, n={n} "
                          f"| p50 {pct(t, 50):.3f} ms, p99 {pct(t, 99):.3f} ms, max {max(t):.1f} ms | "
                          f"p99 ≤ 5 ms |")
    finally:
        r.stop()


if __name__ == "__main__":
    main()
