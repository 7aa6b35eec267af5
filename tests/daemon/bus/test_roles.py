"""Roles for keys: the allow-list files, the permission decision (fuzzed against the command table)
and the command server's check, on plain ipc sockets with stub handlers."""
from __future__ import annotations

import random
import stat
import threading
import time

import pytest
import zmq
import zmq.auth

from daemon.bus import roles
from daemon.bus.auth import KeyRing, create_keypair
from daemon.bus.client import Client
from daemon.bus.protocol import CommandError
from daemon.bus.command_table import COMMANDS, ROLES, CommandTable
from daemon.ritad import config
from daemon.ritad.server import CommandServer, Request

SEED = 20261123


def test_entry_round_trip_is_a_zeromq_certificate(tmp_path):
    public, _ = zmq.curve_keypair()
    roles.write_entry(tmp_path, "bob", public, "operator")
    f = tmp_path / "bob.key"
    assert stat.S_IMODE(f.stat().st_mode) == 0o644  # root writes it, the daemon's user reads it
    assert zmq.auth.load_certificate(str(f)) == (public, None)
    assert roles.read_entry(f) == roles.KeyEntry("bob", public, "operator")
    assert roles.set_role(tmp_path, "bob", "admin").role == "admin"
    assert roles.read_entry(f).public == public
    entries, broken = roles.list_entries(tmp_path)
    assert [e.name for e in entries] == ["bob"] and broken == {}
    roles.revoke(tmp_path, "bob")
    assert not f.exists() and list(tmp_path.iterdir()) == []  # no temp files left behind
    with pytest.raises(LookupError, match="no key named 'bob'"):
        roles.revoke(tmp_path, "bob")


def test_a_file_without_a_role_is_a_viewer_and_a_bad_role_names_the_file(tmp_path):
    public, _ = create_keypair(tmp_path / "laptop", "old")  # pyzmq's own format, no role line
    assert roles.read_entry(public).role == "viewer" == roles.DEFAULT_ROLE
    bad = tmp_path / "eve.key"
    bad.write_text(public.read_text().replace("metadata", 'metadata\n    role = "root"'))
    with pytest.raises(ValueError, match=r"eve\.key: role 'root' is not one of viewer, operator, admin"):
        roles.read_entry(bad)
    entries, broken = roles.list_entries(tmp_path)
    assert entries == [] and "eve.key" in broken


@pytest.mark.parametrize("name, public, role, match", [
    ("../x", b"a" * 40, "viewer", "not a key name"),
    ("bob", b"short", "viewer", "not a 40-character z85"),
    ("bob", b"~" * 40, "viewer", "not a 40-character z85"),
    ("bob", b"a" * 40, "superuser", "role 'superuser' is not one of"),
])
def test_write_entry_refuses_bad_values(tmp_path, name, public, role, match):
    with pytest.raises(ValueError, match=match):
        roles.write_entry(tmp_path, name, public, role)
    assert list(tmp_path.iterdir()) == []


def test_keyring_sees_role_changes_and_revocation_without_a_restart(tmp_path):
    ring = KeyRing(tmp_path)
    public, _ = zmq.curve_keypair()
    assert ring.lookup(public) is None
    roles.write_entry(tmp_path, "bob", public, "viewer")
    assert ring.lookup(public).role == "viewer"
    roles.set_role(tmp_path, "bob", "operator")  # same directory mtime tick: the file's inode changes
    assert ring.lookup(public).role == "operator"
    roles.revoke(tmp_path, "bob")
    assert ring.lookup(public) is None and ring.callback("rita", public) is False


def test_keyring_rescans_for_a_file_edited_in_place(tmp_path):
    """A request stats only the folder; an in-place edit (folder mtime unchanged) is seen at the next rescan."""
    public, _ = zmq.curve_keypair()
    roles.write_entry(tmp_path, "bob", public, "viewer")
    ring = KeyRing(tmp_path, rescan_s=1.0)
    ring.RACY_NS = -10**12  # this test only: trust the folder's mtime however recent
    assert ring.lookup(public).role == "viewer"
    f = tmp_path / "bob.key"
    f.write_text(f.read_text().replace('role = "viewer"', 'role = "admin"'))  # same inode, folder untouched
    assert ring.lookup(public).role == "viewer"  # not scanned: one stat said nothing changed
    time.sleep(1.05)
    assert ring.lookup(public).role == "admin"


def test_fixed_facts_of_the_table():
    """The acceptance cases, spelled out (the fuzz below checks the rule itself)."""
    from daemon.ritad import plugins

    table = CommandTable()
    plugins.installed(table)  # a daemon's table: the simulator's commands too
    for cmd in ("status", "state", "ping", "hello", "help", "calib.results", "calib.jobs",
                "files.list", "files.read", "robot.status", "camera.status", "robot.stop"):
        assert roles.may("viewer", cmd), cmd  # stopping is never forbidden
    for cmd in ("robot.move", "robot.turn", "robot.release", "calib.start", "calib.resume", "capture",
                "camera.capture", "tracker.aim", "tracker.find", "sim.place_robot_on_plate"):
        assert not roles.may("viewer", cmd, table) and roles.may("operator", cmd, table), cmd
    assert roles.required_role("sim.place_robot_on_plate") == "admin"  # a table without it: fail closed
    for cmd in ("keys.list", "keys.allow", "keys.role", "keys.revoke"):
        assert not roles.may("operator", cmd) and roles.may("admin", cmd), cmd
    assert roles.refusal("robot.move", "viewer", "key bob") == "robot.move needs role operator; key bob is viewer"
    assert {n for n, c in COMMANDS.items() if c.motion} >= {"robot.move", "robot.turn", "robot.stop"}


def _oracle(role: str, cmd: str) -> bool:
    """Allowed-sets built from the table's rows, independent of roles.may's ranking code."""
    allowed = {"viewer": {c.name for c in COMMANDS.values() if c.role == "viewer"}}
    allowed["operator"] = allowed["viewer"] | {c.name for c in COMMANDS.values() if c.role == "operator"}
    allowed["admin"] = set(COMMANDS) | {cmd}  # admin: everything, also what the table does not know
    return cmd in allowed.get(role, set())


def _random_command(rng: random.Random) -> str:
    if rng.random() < 0.8:
        return rng.choice(sorted(COMMANDS))
    return rng.choice(["keys", "robot.moveX", "", "ROBOT.MOVE", "admin", "keys.*", "x" * 70, "robot.move "])


def test_permission_fuzz_against_the_table():
    rng = random.Random(SEED)
    seen = set()
    for _ in range(5000):
        role = rng.choice([*ROLES, *ROLES, "", "root", "Admin", "operator "])
        cmd = _random_command(rng)
        got = roles.may(role, cmd)
        assert got == _oracle(role, cmd), (role, cmd)
        assert (roles.refusal(cmd, role, "key k") is None) == got
        seen.add((role in ROLES, got))
    assert seen == {(True, True), (True, False), (False, False)}


# ------------------------------------------------------------------ the server's check, end to end over ipc


@pytest.fixture(scope="module")
def servers(tmp_path_factory):
    """One command server per ipc role, with stub handlers for every table command plus one off-table."""
    tmp = tmp_path_factory.mktemp("roles")
    ctx = zmq.Context()
    ran: list[Request] = []
    lock = threading.Lock()

    def stub(req: Request) -> dict:
        with lock:
            ran.append(req)
        return {"ran": req.cmd, "role": req.role}

    handlers = {name: stub for name in [*COMMANDS, "debug.off_table"]}
    out = {}
    for role in ROLES:
        s = CommandServer(ctx, [f"ipc://{tmp}/{role}"], handlers, plain_role=role)
        s.start()
        out[role] = s
    yield out, ran
    for s in out.values():
        s.stop()
    ctx.term()


def test_server_fuzz_random_commands_by_role(servers):
    servers_, ran = servers
    rng = random.Random(SEED + 1)
    clients = {r: Client(s.endpoints[0], timeout=5) for r, s in servers_.items()}
    counts = {"ok": 0, "forbidden": 0, "unknown_command": 0}
    try:
        for _ in range(1500):
            role = rng.choice(ROLES)
            cmd = rng.choice([_random_command(rng), "debug.off_table"]) if rng.random() < 0.1 else _random_command(rng)
            args = {"confirm": rng.random() < 0.5, "x": rng.uniform(-1, 1)} if rng.random() < 0.5 else {}
            if not cmd:
                continue
            before = len(ran)
            try:
                result, code, message = clients[role].call_raw(cmd, args)[0], "ok", ""
            except CommandError as exc:
                result, code, message = None, exc.code, exc.args[0]
            if cmd not in servers_[role].handlers:
                assert code == "unknown_command", (role, cmd, message)
            elif roles.may(role, cmd):
                assert code == "ok" and result == {"ran": cmd, "role": role}, (role, cmd, message)
            else:
                assert code == "forbidden", (role, cmd, code)
                need = COMMANDS[cmd].role if cmd in COMMANDS else "admin"
                assert message == f"{cmd} needs role {need}; local client is {role}"
                assert len(ran) == before  # the handler never ran
            counts[code] += 1
    finally:
        for c in clients.values():
            c.close()
    assert min(counts.values()) > 20, counts  # every outcome was exercised


SIM = {"devices": {"camera": "sim:", "tracker": "sim:", "robot": "sim:"}}  # every device URL is required


def test_ipc_role_is_configurable_and_checked():
    cfg = config.from_dict({**SIM, "security": {"ipc_role": "viewer"}})
    assert cfg.security.ipc_role == "viewer"
    assert config.from_dict(SIM).security.ipc_role == "operator"
    with pytest.raises(config.ConfigError, match="security.ipc_role 'root' is not one of viewer, operator, admin"):
        config.from_dict({**SIM, "security": {"ipc_role": "root"}})
    with pytest.raises(config.ConfigError, match="worker connects over ipc and needs operator"):
        config.from_dict({**SIM, "security": {"ipc_role": "viewer"}, "daemon": {"start_worker": True}})
