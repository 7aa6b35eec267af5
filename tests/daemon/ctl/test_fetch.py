"""ritactl fetch and the files.* bus commands: confined to the data dir, chunked, resumable, atomic.

An in-process sim daemon serves a data dir holding datasets, secrets and symlinks
that lead outside; the tests try to climb out, check that secrets are never served,
copy everything, interrupt a copy and resume it, and change a file mid-copy.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import pytest

from daemon.ritad import config
from daemon.ctl import main as ctl
from daemon.bus.client import Client
from daemon.ctl.fetch import FetchError, fetch, fetch_file, local_target
from daemon.ritad.files import CHUNK_MAX
from daemon.ritad.daemon import Daemon
from daemon.bus.protocol import CommandError

BIG = 2_600_000  # bytes: several chunks at the small chunk size below
SMALL_CHUNK = 256 * 1024


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[Daemon, Path, Path]]:
    """A sim daemon (devices not waited for: files.* need none) and its populated data dir."""
    cfg = config.sim_config(tmp_path / "rt", tmp_path / "data")
    cfg.daemon.start_worker = False
    cfg.devices.camera = "sim:?size=64x48&noise=0"
    d = Daemon(cfg)
    d.start()
    data = Path(cfg.daemon.data_dir)
    rng = np.random.default_rng(11)
    files = {"datasets/run1/0000-a.png": rng.bytes(BIG), "datasets/run1/0000-a.json": b'{"label": "a"}\n',
             "datasets/run1/dataset.json": b"{}\n", "calibration/active.json": b'{"verdict": "ok"}\n',
             "report.md": b"# report\n", "empty.txt": b""}
    for rel, body in files.items():
        (data / rel).parent.mkdir(parents=True, exist_ok=True)
        (data / rel).write_bytes(body)
        os.chmod(data / rel, 0o600)
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.txt").write_text("not yours")
    (data / "keys").mkdir()
    (data / "keys" / "server.key_secret").write_text("secret")
    (data / "authorized_keys").mkdir()
    (data / "authorized_keys" / "bob.key").write_text("public")
    (data / "datasets" / "stray.key_secret").write_text("secret")
    (data / "datasets" / "run1" / ".0001-b.png.x.tmp").write_bytes(b"half")
    (data / "link_out").symlink_to(outside)
    (data / "link_file_out").symlink_to(outside / "secret.txt")
    (data / "link_in").symlink_to(data / "report.md")
    (data / "loop").symlink_to(data / "loop")
    try:
        yield d, data, tmp_path
    finally:
        d.stop()


def client(d: Daemon) -> Client:
    return Client(d.server.endpoints[0], timeout=10)


class Flaky(Client):
    """A client that runs ``hook(cmd, args, nth_read)`` before each request."""

    def __init__(self, endpoint: str, hook: Callable[[str, dict[str, Any], int], None]) -> None:
        super().__init__(endpoint, timeout=10)
        self.hook = hook
        self.reads: list[int] = []

    def call_raw(self, cmd: str, args: dict[str, Any] | None = None, timeout: float | None = None) -> Any:
        args = args or {}
        if cmd == "files.read":
            self.reads.append(args["offset"])
        self.hook(cmd, args, len(self.reads))
        return super().call_raw(cmd, args, timeout)


def test_list_serves_data_but_never_secrets_or_escapes(served) -> None:
    d, data, _ = served
    with client(d) as c:
        listed = {f["path"]: f["size"] for f in c.call("files.list")["files"]
                  if not f["path"].startswith("sim/")  # the sim installer's files: test_messages.py
                  and f["path"] != "calibration/tracker_station.json"}  # and its tracker station
        sub = c.call("files.list", path="datasets")["files"]
    assert listed == {"calibration/active.json": 18, "datasets/run1/0000-a.json": 15,
                      "datasets/run1/0000-a.png": BIG, "datasets/run1/dataset.json": 3, "empty.txt": 0,
                      "link_in": 9, "report.md": 9}
    assert {f["path"] for f in sub} == {p for p in listed if p.startswith("datasets/")}


ESCAPES = ("../outside/secret.txt", "/etc/passwd", "datasets/../../outside/secret.txt", "C:/Windows/win.ini",
           "datasets\\..\\..\\x", "link_out/secret.txt", "link_file_out", "link_out", "keys/server.key_secret",
           "keys", "authorized_keys/bob.key", "datasets/stray.key_secret", "report.md\x00.png", "loop", "loop/x",
           "a" * 5000)


def test_path_escape_attempts_are_refused(served) -> None:
    d, _, _ = served
    with client(d) as c:
        for path in ESCAPES:
            for cmd, extra in (("files.read", {"offset": 0, "length": 10}), ("files.hash", {}), ("files.list", {})):
                with pytest.raises(CommandError) as ei:
                    c.call(cmd, path=path, **extra)
                assert ei.value.code == "bad_args", (cmd, path, ei.value)
                assert repr(path) in ei.value.args[0], ei.value.args[0]


def test_read_chunks_and_argument_checks(served) -> None:
    d, data, _ = served
    body = (data / "datasets/run1/0000-a.png").read_bytes()
    with client(d) as c:
        meta, extra = c.call_raw("files.read", {"path": "datasets/run1/0000-a.png", "offset": 1000, "length": 500})
        assert bytes(extra[0].buffer) == body[1000:1500] and meta["size"] == BIG and not meta["eof"]
        meta, extra = c.call_raw("files.read", {"path": "datasets/run1/0000-a.png", "offset": BIG - 10,
                                                "length": CHUNK_MAX})
        assert bytes(extra[0].buffer) == body[-10:] and meta["eof"] and meta["length"] == 10
        assert c.call("files.hash", path="report.md", length=3)["sha256"] == hashlib.sha256(b"# r").hexdigest()
        for args, word in (({"length": CHUNK_MAX + 1}, "length"), ({"length": 0}, "length"),
                           ({"offset": -1}, "offset"), ({"offset": True}, "offset"), ({"path": 3}, "path")):
            with pytest.raises(CommandError) as ei:
                c.call("files.read", **{"path": "report.md", "offset": 0, "length": 10, **args})
            assert ei.value.code == "bad_args" and word in ei.value.args[0]
        with pytest.raises(CommandError) as ei:
            c.call("files.read", path="nope.txt", offset=0, length=10)
        assert ei.value.code == "not_found" and "nope.txt" in ei.value.args[0]
        with pytest.raises(CommandError, match="not a file"):
            c.call("files.read", path="datasets", offset=0, length=10)
        assert c.call("ping")["pong"]  # the daemon kept serving


def test_fetch_copies_datasets_results_and_reports_then_skips(served, capsys) -> None:
    d, data, tmp = served
    dest = tmp / "laptop"
    ep = d.server.endpoints[0]
    for own in ("worker.log", "stop_latch.json", "ritad.lock"):  # the daemon's housekeeping (issue 35)
        (data / own).write_text("{}\n")
    assert ctl.main(["--endpoint", ep, "fetch", "--to", str(dest)]) == 0
    for rel in ("datasets/run1/0000-a.png", "calibration/active.json"):
        assert (dest / rel).read_bytes() == (data / rel).read_bytes(), rel
    taken = {p.relative_to(dest).parts[0] for p in dest.rglob("*") if p.is_file()}
    assert taken == {"datasets", "calibration"}, taken  # not ritad.lock, stop_latch.json, worker.log, sim/
    assert not list(dest.rglob("*.part"))
    capsys.readouterr()
    assert ctl.main(["--endpoint", ep, "--json", "fetch", "--to", str(dest)]) == 0
    import json

    r = json.loads(capsys.readouterr().out)
    # datasets/run1's three, calibration/'s two (active.json, the sim's tracker station)
    assert r["fetched"] == [] and len(r["skipped"]) == 3 + 2 and r["errors"] == {}
    assert ctl.main(["--endpoint", ep, "fetch", "report.md", "empty.txt", "--to", str(dest)]) == 0
    for rel in ("report.md", "empty.txt"):  # a PATH names what it wants
        assert (dest / rel).read_bytes() == (data / rel).read_bytes(), rel
    capsys.readouterr()
    assert ctl.main(["--endpoint", ep, "fetch", "--quiet", "--to", str(tmp / "quiet")]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 1 and out[0].startswith("5 fetched, 0 resumed"), out  # the summary alone


def test_fetch_of_a_robot_without_procedures_yet(served, capsys) -> None:
    d, data, tmp = served
    assert not (data / "procedures").exists()  # a default folder that is not there yet lists nothing
    assert ctl.main(["--endpoint", d.server.endpoints[0], "fetch", "-q", "--to", str(tmp / "l")]) == 0
    assert ctl.main(["--endpoint", d.server.endpoints[0], "fetch", "procedures", "--to", str(tmp / "l")]) == 4


def test_interrupted_fetch_resumes_where_it_stopped(served) -> None:
    d, data, tmp = served
    rel, dest = "datasets/run1/0000-a.png", tmp / "laptop"

    def interrupt(cmd: str, args: dict[str, Any], reads: int) -> None:
        if cmd == "files.read" and reads == 4:
            raise KeyboardInterrupt  # Ctrl-C (or a dropped link) during the 4th chunk

    with Flaky(d.server.endpoints[0], interrupt) as c, pytest.raises(KeyboardInterrupt):
        fetch_file(c, rel, BIG, dest, chunk=SMALL_CHUNK)
    part = dest / "datasets/run1/.0000-a.png.part"
    assert part.stat().st_size == 3 * SMALL_CHUNK and not (dest / rel).exists()
    with Flaky(d.server.endpoints[0], lambda *_: None) as c:
        assert fetch_file(c, rel, BIG, dest, chunk=SMALL_CHUNK) == "resumed"
        assert c.reads[0] == 3 * SMALL_CHUNK  # nothing read twice
        assert len(c.reads) == -(-(BIG - 3 * SMALL_CHUNK) // SMALL_CHUNK)
    assert (dest / rel).read_bytes() == (data / rel).read_bytes() and not part.exists()


def test_resume_with_a_corrupt_part_starts_over(served) -> None:
    d, data, tmp = served
    rel, dest = "datasets/run1/0000-a.png", tmp / "laptop"
    part = dest / "datasets/run1/.0000-a.png.part"
    part.parent.mkdir(parents=True)
    part.write_bytes(b"\xff" * SMALL_CHUNK)  # right size, wrong bytes
    with Flaky(d.server.endpoints[0], lambda *_: None) as c:
        assert fetch_file(c, rel, BIG, dest, chunk=SMALL_CHUNK) == "fetched"
        assert c.reads[0] == 0
    assert (dest / rel).read_bytes() == (data / rel).read_bytes()


def test_a_file_changed_during_the_copy_is_copied_again(served) -> None:
    d, data, tmp = served
    rel, dest = "datasets/run1/0000-a.png", tmp / "laptop"
    new = np.random.default_rng(12).bytes(BIG + 7)

    def rewrite(cmd: str, args: dict[str, Any], reads: int) -> None:
        if cmd == "files.read" and reads == 2:
            (data / rel).write_bytes(new)  # the robot rewrites it while we copy

    with Flaky(d.server.endpoints[0], rewrite) as c:
        assert fetch_file(c, rel, BIG, dest, chunk=SMALL_CHUNK) == "fetched"
    assert (dest / rel).read_bytes() == new

    def always(cmd: str, args: dict[str, Any], reads: int) -> None:
        if cmd == "files.hash" and args.get("length") is None:  # changed again before every check
            (data / rel).write_bytes(np.random.default_rng(reads).bytes(3 * SMALL_CHUNK // 2))

    with Flaky(d.server.endpoints[0], always) as c:
        r = fetch(c, [rel], tmp / "again", chunk=SMALL_CHUNK, say=lambda _: None)
    assert "kept changing" in r["errors"][rel] and not (tmp / "again" / rel).exists()


def test_a_listing_that_would_leave_the_target_is_refused(tmp_path: Path) -> None:
    for rel in ("../x", "/etc/x", "a/../../x", "C:/x", "a\\b", ""):
        with pytest.raises(FetchError):
            local_target(tmp_path, rel)
    assert local_target(tmp_path, "a/b.png") == tmp_path / "a" / "b.png"


def test_progress_bar_only_on_a_terminal(monkeypatch) -> None:
    import io

    from daemon.ctl.fetch import Progress

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    err = Tty()
    monkeypatch.setattr("sys.stderr", err)
    p = Progress(4_000_000, tty=True)
    p.add(1_000_000, "datasets/a.png")
    p.add(3_000_000, "datasets/b.png")  # the last update is always drawn
    p.end()
    drawn = err.getvalue().split("\r")
    assert " 25.0%" in drawn[1] and "datasets/a.png" in drawn[1]
    assert drawn[-1].startswith("[" + "#" * 30 + "] 100.0%") and drawn[-1].endswith("\n")
    err2 = io.StringIO()
    monkeypatch.setattr("sys.stderr", err2)
    q = Progress(10, tty=False)
    q.add(10, "x")
    q.end()
    assert err2.getvalue() == ""


def test_ctrl_c_during_fetch_says_how_to_resume(served, monkeypatch, capsys) -> None:
    d, _, tmp = served

    def interrupted(*args: Any, **kw: Any) -> str:
        raise KeyboardInterrupt

    monkeypatch.setattr("daemon.ctl.fetch.fetch_file", interrupted)
    assert ctl.main(["--endpoint", d.server.endpoints[0], "fetch", "--to", str(tmp / "laptop")]) == 130
    assert "run the same `ritactl fetch` again to resume" in capsys.readouterr().err


def test_fetch_over_curve_tcp_never_carries_the_keys(tmp_path: Path) -> None:
    """The laptop's real path: tcp with CURVE; 1 MiB attachments arrive intact, secrets stay home."""
    import signal
    import subprocess
    import sys

    from daemon.bus.auth import create_keypair, load_keypair, load_public
    from tests.daemon.bus.test_curve import ROOT, curve_config

    data = tmp_path / "data"
    create_keypair(data / "keys", "server")
    create_keypair(tmp_path / "clients", "alice")
    (data / "authorized_keys").mkdir(parents=True)
    (data / "authorized_keys" / "alice.key").write_bytes((tmp_path / "clients" / "alice.key").read_bytes())
    (data / "datasets" / "d").mkdir(parents=True)
    body = np.random.default_rng(5).bytes(3 * CHUNK_MAX + 123)
    (data / "datasets" / "d" / "x.png").write_bytes(body)
    (tmp_path / "ritad.toml").write_text(curve_config(tmp_path))
    proc = subprocess.Popen([sys.executable, "-m", "daemon.ritad.main", "--config", str(tmp_path / "ritad.toml")],
                            cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE,
                            stderr=open(tmp_path / "ritad.log", "w"), text=True)
    try:
        line = proc.stdout.readline()
        assert line.startswith("ritad ready"), (line, (tmp_path / "ritad.log").read_text())
        tcp = next(e for e in line.split(": ", 1)[1].split() if e.startswith("tcp://"))
        public, secret = load_keypair(tmp_path / "clients" / "alice.key_secret")
        keys = {"public": public, "secret": secret, "server": load_public(data / "keys" / "server.key")}
        with Client(tcp, timeout=10, curve=keys) as c:
            r = fetch(c, [], tmp_path / "laptop", say=lambda _: None)
        assert r["errors"] == {} and "datasets/d/x.png" in r["fetched"]
        assert (tmp_path / "laptop" / "datasets" / "d" / "x.png").read_bytes() == body
        got = {p.relative_to(tmp_path / "laptop").as_posix() for p in (tmp_path / "laptop").rglob("*")}
        assert not any(p.startswith(("keys", "authorized_keys")) or "key_secret" in p for p in got), got
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(10)
