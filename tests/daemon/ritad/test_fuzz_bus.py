"""Fuzzing the command socket of a running daemon: every message gets exactly one reply.

An in-process ``Daemon`` on the simulated world (small camera images, a fast tracker
fake, no calibration worker) receives batches of random requests on one DEALER:
random bytes, random msgpack values, maps with missing or wrong-typed ``v``/``id``/
``cmd``/``args`` and real command names with random arguments. Which commands and
arguments exist, and the types, range edges and choices the values are drawn around,
come from the command table (``daemon/bus/command_table.py``). Motion commands are
never sent with ``confirm: true`` and long polls are kept short. Each batch must
get exactly one well-formed reply per message (the id echoed when the envelope was
valid, ``null`` otherwise), never an ``internal`` error, and ``status`` must still
answer afterwards.
"""
from __future__ import annotations

import collections
import contextlib
import itertools
import math
import re
import string
import time
from pathlib import Path
from typing import Any, Iterator

import msgpack
import pytest
import zmq
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from daemon.bus.command_table import CommandTable
from daemon.bus.command_table import Arg
from daemon.bus.client import Client
from fakes.operator import lock_on_robot
from daemon.ritad import plugins
from daemon.ritad.daemon import Daemon
from daemon.ritad.stop_latch import LATCH_FILE
from daemon.bus.protocol import CommandError, ErrorCode, pack, unpack
from tests.ritad_up import ritad_in_process
from tests.fuzzscale import cases, scaled

NAMES = (120, 60)  # capture-name examples: full run, make-test sample

BATCH = 40
EXAMPLES = cases(340, 120)  # × BATCH messages: 13,600 in the full run (over 10,000 of them distinct)
MOTION = ("robot.move", "robot.turn")
SLOW = ("sim.survey_images",)  # renders photographs: seconds per view
CODE_RE = re.compile(r"^[a-z][a-z0-9_]*$|^(tracker|robot|camera)_\w+$")
_MISSING = object()

# ---------------------------------------------------------------------------- strategies

scalars = st.one_of(st.none(), st.booleans(), st.integers(-(1 << 63), (1 << 64) - 1),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12), st.binary(max_size=12))
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=3),
    st.dictionaries(st.one_of(st.text(max_size=6), st.integers(-3, 3)), inner, max_size=3)), max_leaves=6)
numbers = st.one_of(st.floats(-100, 100), st.floats(-1e4, 1e4), st.integers(-10**6, 10**6),
                    st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from([0, 0.0, -0.0, 1e308, -1e308, 5e-324, 10001.0]))
texts = st.one_of(st.text(max_size=30), st.text(string.ascii_letters, min_size=250, max_size=300),
                  st.sampled_from(["", ".", "..", "/", "a/b", "x" * 300]))

# Strings that probe paths and names; every str argument gets them (they are not tied to one argument).
NASTY_TEXTS = st.sampled_from(["../etc/passwd", "/etc/passwd", "keys/server.key_secret", "worker.log", "C:/x",
                               "a\\..\\b", "sim", "sim/plate.json", "a" * 5000])
TYPED: dict[str, st.SearchStrategy[Any]] = {"float": numbers, "int": numbers, "bool": st.booleans(),
                                            "str": texts | NASTY_TEXTS, "map": st.dictionaries(st.text(max_size=6),
                                                                                             values, max_size=3),
                                            "any": values}


def edges(arg: Arg) -> list[float]:
    """The table's range limits and their neighbours: where an off-by-one would show."""
    out: list[float] = []
    for limit in (arg.lo, arg.hi):
        if limit is not None:
            out += [limit, math.nextafter(limit, -math.inf), math.nextafter(limit, math.inf), limit - 1, limit + 1]
            out += [int(limit) - 1, int(limit), int(limit) + 1]
    return out


def arg_value(arg: Arg) -> st.SearchStrategy[Any]:
    """Values for ``arg`` derived from its table entry: its type, range edges, choices, and anything else."""
    s = TYPED[arg.type]
    if arg.choices:
        s = st.sampled_from(arg.choices) | s
    if edges(arg):
        s = st.sampled_from(edges(arg)) | s
    return s | values


# every command of the table (the daemon's ``help`` is checked against it)
TABLE_COMMANDS = CommandTable()
plugins.installed(TABLE_COMMANDS)  # the table a daemon serves: the installed plugins' commands too
COMMANDS = sorted(TABLE_COMMANDS)


@st.composite
def command_args(draw: st.DrawFn, cmd: str) -> dict[Any, Any]:
    """Known argument names with random (often wrong) values, plus stray keys."""
    args: dict[Any, Any] = {a.name: draw(arg_value(a)) for a in TABLE_COMMANDS[cmd].args if draw(st.booleans())}
    args.update(draw(st.dictionaries(st.text(max_size=8), values, max_size=2)))
    return make_safe(cmd, args)


def make_safe(cmd: str, args: Any) -> Any:
    """Never confirm a motion; keep worker long polls short (they would hold the reply)."""
    if not isinstance(args, dict):
        return args
    if cmd in MOTION and args.get("confirm") is True:
        args["confirm"] = False
    if cmd in SLOW:  # a valid request renders for tens of seconds: keep it fuzzed, always refused
        args["views"] = 0
    if cmd == "robot.commission":  # a valid one runs the base's checks for seconds: fuzzed, always refused
        args["clock_s"] = 0.0
    if cmd in ("calib.next", "calib.inbox"):
        t = args.get("timeout_s", _MISSING)
        if t is _MISSING or (isinstance(t, (int, float)) and not isinstance(t, bool) and 0 <= t <= 60):
            args["timeout_s"] = 0.0 if t is _MISSING or math.isnan(t) else float(t) % 0.05
    return args


ID_KINDS = st.sampled_from(["str", "str", "int", "int", "missing", "none", "float", "bool", "list", "map", "bytes"])


@st.composite
def envelope_map(draw: st.DrawFn) -> dict[str, Any]:
    """A request map whose v/id/cmd/args may each be missing or of a wrong type."""
    msg: dict[Any, Any] = {}
    v = draw(st.sampled_from([1, 1, 1, _MISSING, 2, 0, "1", None, 1.0, [1]]))
    if v is not _MISSING:
        msg["v"] = v
    cmd = draw(st.one_of(st.sampled_from(COMMANDS), st.just(_MISSING), st.text(max_size=12), values))
    if cmd is not _MISSING:
        msg["cmd"] = cmd
    args = draw(st.one_of(st.just(_MISSING), st.none(), st.dictionaries(st.text(max_size=6), values, max_size=3),
                          values))
    if (cmd == "calib.next" or cmd in SLOW) and args in (_MISSING, None):
        args = {}  # the default long poll (10 s) or render would hold the batch
    if args is not _MISSING:
        msg["args"] = make_safe(cmd if isinstance(cmd, str) else "", args)
    msg["id"] = draw(ID_KINDS)
    msg.update(draw(st.dictionaries(st.text(max_size=5).filter(lambda k: k not in msg), values, max_size=2)))
    return msg


@st.composite
def known_command(draw: st.DrawFn) -> dict[str, Any]:
    cmd = draw(st.sampled_from(COMMANDS))
    return {"v": 1, "id": draw(st.sampled_from(["str", "int"])), "cmd": cmd, "args": draw(command_args(cmd))}


messages = st.one_of(
    st.one_of(st.binary(min_size=1, max_size=120), values.map(pack)).map(lambda b: ("raw", b)),
    envelope_map().map(lambda m: ("map", m)),
    known_command().map(lambda m: ("map", m)),
    known_command().map(lambda m: ("map", m)),
    known_command().map(lambda m: ("map", m)),
)

# ---------------------------------------------------------------------------- oracle


def expected(body: bytes) -> tuple[Any, str | None]:
    """(id the reply must carry, envelope error code or None) per docs/protocol.md."""
    try:
        msg = unpack(body)
    except Exception:
        return None, ErrorCode.BAD_REQUEST
    if not isinstance(msg, dict):
        return None, ErrorCode.BAD_REQUEST
    if msg.get("v", 1) != 1:
        return None, ErrorCode.UNSUPPORTED_VERSION
    if not isinstance(msg.get("cmd"), str) or not msg["cmd"]:
        return None, ErrorCode.BAD_REQUEST
    rid = msg.get("id", _MISSING)
    if rid is _MISSING or not isinstance(rid, (str, int)) or isinstance(rid, bool):
        return None, ErrorCode.BAD_REQUEST
    if msg.get("args") is not None and not isinstance(msg.get("args", {}), dict):
        return None, ErrorCode.BAD_ARGS
    return rid, None


_ids = itertools.count(1)
_ID_VALUES = {"missing": _MISSING, "none": None, "float": 1.5, "bool": True, "list": [1], "map": {"a": 1},
              "bytes": b"id"}


def encode(kind: str, item: Any) -> bytes:
    """Bytes to send; symbolic ids become unique values so replies can be matched."""
    if kind == "raw":
        return item
    msg = dict(item)
    id_kind = msg.pop("id")
    n = next(_ids)
    if id_kind == "str":
        msg["id"] = f"fz-{n}"
    elif id_kind == "int":
        msg["id"] = n if n % 2 else -n
    elif _ID_VALUES[id_kind] is not _MISSING:
        msg["id"] = _ID_VALUES[id_kind]
    return msgpack.packb(msg, use_bin_type=True)


def check_reply(frames: list[bytes]) -> dict[str, Any]:
    rep = unpack(frames[0])
    assert isinstance(rep, dict) and rep.get("v") == 1, rep
    assert isinstance(rep.get("ok"), bool), rep
    if rep["ok"]:
        assert "result" in rep
    else:
        err = rep["error"]
        assert CODE_RE.match(err["code"]), err
        assert isinstance(err["message"], str) and err["message"], err
        assert err["code"] != ErrorCode.INTERNAL, f"internal error (a daemon bug): {err}"
    return rep


# ---------------------------------------------------------------------------- daemon


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory):
    with ritad_in_process(tmp_path_factory.mktemp("fuzzbus"), timeout=30, tracker="sim:?time_scale=0.002") as (d, _):
        yield d


@contextlib.contextmanager
def fresh_dealer(d: Daemon) -> Iterator[zmq.Socket]:
    s = zmq.Context.instance().socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    s.connect(d.server.endpoints[0])
    try:
        yield s
    finally:
        s.close()


@pytest.fixture
def dealer(daemon: Daemon) -> Iterator[zmq.Socket]:
    with fresh_dealer(daemon) as s:
        yield s


def exchange(sock: zmq.Socket, bodies: list[bytes], timeout: float = 30.0) -> list[dict[str, Any]]:
    """Send every body, then collect exactly one reply each (and check there is no extra)."""
    for b in bodies:
        sock.send(b)
    replies = []
    end = time.monotonic() + timeout
    while len(replies) < len(bodies):
        left = end - time.monotonic()
        assert left > 0 and sock.poll(int(left * 1000)), f"only {len(replies)} of {len(bodies)} replies"
        replies.append(check_reply(sock.recv_multipart()))
    return replies


def match(bodies: list[bytes], replies: list[dict[str, Any]]) -> None:
    """Each valid-envelope request got its own id back; the rest got null ids with the right codes."""
    want_ids: collections.Counter = collections.Counter()
    want_codes: collections.Counter = collections.Counter()
    for b in bodies:
        rid, code = expected(b)
        if code is None:
            want_ids[rid] += 1
        else:
            want_codes[code] += 1
    got_ids = collections.Counter(r["id"] for r in replies if r["id"] is not None)
    got_codes = collections.Counter(r["error"]["code"] for r in replies if r["id"] is None)
    assert got_ids == want_ids
    assert got_codes == want_codes


def test_command_names_cover_the_daemon(daemon: Daemon) -> None:
    """The fuzzer knows every command the daemon offers (so none escapes fuzzing), and help says what the table says."""
    with Client(daemon.server.endpoints[0], timeout=10) as c:
        offered = c.call("help")["commands"]
    assert set(offered) == set(COMMANDS)
    assert offered["robot.move"]["role"] == "operator" and offered["robot.move"]["args"][0]["unit"] == "mm"


def test_random_messages_each_get_one_reply(daemon: Daemon) -> None:
    sent = [0]
    distinct: set[str] = set()
    codes: collections.Counter = collections.Counter()
    t0 = time.monotonic()

    @settings(max_examples=EXAMPLES, derandomize=True, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(batch=st.lists(messages, min_size=BATCH, max_size=BATCH, unique_by=repr))
    def run(batch: list[tuple[str, Any]]) -> None:
        bodies = [encode(kind, item) for kind, item in batch]
        with fresh_dealer(daemon) as sock:  # a failed example's late replies must not leak into the next
            replies = exchange(sock, bodies)
            match(bodies, replies)
            sent[0] += len(bodies)
            distinct.update(repr(m) for m in batch)  # before ids are made unique
            codes.update("ok" if r["ok"] else r["error"]["code"] for r in replies)
            probe = encode("map", {"v": 1, "id": "str", "cmd": "status", "args": {}})
            status = exchange(sock, [probe])[0]
            assert status["id"] == unpack(probe)["id"], f"an extra reply arrived: {status}"
            assert status["ok"] and status["result"]["alive"] is True

    run()
    elapsed = time.monotonic() - t0
    print(f"\nbus fuzz: {sent[0]} messages ({len(distinct)} distinct) in {elapsed:.1f} s; "
          f"replies by code: {dict(codes.most_common())}")
    assert len(distinct) >= 0.73 * EXAMPLES * BATCH  # full run: >= 10,000 distinct
    with Client(daemon.server.endpoints[0], timeout=10) as c:
        h = c.wait_ready(timeout=30)
    assert h["alive"] is True
    assert h["commands"]["requests"] >= sent[0]
    assert codes["ok"] > 0 and codes[ErrorCode.BAD_ARGS] > 0 and codes[ErrorCode.CONFIRM_REQUIRED] > 0
    # random labels and dataset names ("..", ".", "a/b", 300 characters) stay inside datasets/
    data = Path(daemon.config.daemon.data_dir)
    # sim: the installer's files, calibration: its tracker station; the stop latch's file once a random
    # robot.stop came by
    assert sorted(p.name for p in data.iterdir() if p.name != LATCH_FILE) == ["calibration", "datasets", "sim"]
    assert [p.name for p in (data / "calibration").iterdir()] == ["tracker_station.json"]
    folders = list((data / "datasets").iterdir())
    assert folders and all(p.is_dir() and not p.name.startswith(".") for p in folders), folders


def test_oversized_and_empty_requests(daemon: Daemon, dealer: zmq.Socket) -> None:
    limit = daemon.config.daemon.max_message_bytes
    big = pack({"v": 1, "id": "big", "cmd": "ping", "args": {"pad": b"x" * limit}})
    replies = exchange(dealer, [big, b"", b"\xc1"])
    assert [r["error"]["code"] for r in replies] == [ErrorCode.TOO_LARGE, ErrorCode.BAD_REQUEST,
                                                      ErrorCode.BAD_REQUEST]
    assert str(limit) in replies[0]["error"]["message"]
    assert exchange(dealer, [pack({"v": 1, "id": 7, "cmd": "ping"})])[0]["result"]["pong"] is True


def test_capture_names_stay_inside_datasets(daemon: Daemon) -> None:
    """Random labels and dataset names on captures that succeed: files land under datasets/ only."""
    data = Path(daemon.config.daemon.data_dir)
    with Client(daemon.server.endpoints[0], timeout=30) as c:
        c.wait_ready(timeout=30)
        c.call("robot.release")  # the fuzz above may have sent robot.stop: aiming the tracker is a motion
        lock_on_robot(c)
        saved: list[Path] = []

        @settings(max_examples=cases(*NAMES), derandomize=True, deadline=None, database=None,
                  suppress_health_check=list(HealthCheck))
        @given(label=texts, dataset=st.none() | texts)
        def run(label: str, dataset: str | None) -> None:
            r = c.call("capture", label=label, dataset=dataset)
            path = Path(r["path"]).resolve()
            assert path.parent.parent == (data / "datasets").resolve(), path
            assert path.is_file() and len(path.name) < 255
            saved.append(path)

        run()
    assert len(saved) >= scaled(100, *NAMES)
    # sim: the installer's files, calibration: its tracker station; the stop latch's file once a random
    # robot.stop came by
    assert sorted(p.name for p in data.iterdir() if p.name != LATCH_FILE) == ["calibration", "datasets", "sim"]
    assert [p.name for p in (data / "calibration").iterdir()] == ["tracker_station.json"]


@pytest.mark.parametrize("cmd,args,code,words", [
    ("robot.turn", {"angle_deg": 400, "confirm": True}, ErrorCode.BAD_ARGS, ["'angle_deg'", "[-360, 360] °"]),
    ("robot.move", {"distance_mm": 1e6}, ErrorCode.BAD_ARGS, ["|distance_mm|", "configured limit 2000"]),
    ("robot.move", {"distance_mm": 10, "speed_mm_s": 1e4}, ErrorCode.BAD_ARGS, ["speed_mm_s", "configured limit"]),
    ("robot.move", {"distance_mm": 10}, ErrorCode.CONFIRM_REQUIRED, ["confirm=true", "--yes"]),
    ("tracker.aim", {"x": "a", "y": 0, "z": 0}, ErrorCode.BAD_ARGS, ["'x'", "must be float (mm)"]),
    ("files.read", {}, ErrorCode.BAD_ARGS, ["missing argument 'path'"]),
])
def test_the_daemon_checks_arguments_by_the_table_then_the_config(daemon: Daemon, cmd, args, code, words) -> None:
    """Over the bus: table checks (type, range) first, then the config's limits, then the confirmation."""
    with Client(daemon.server.endpoints[0], timeout=10) as c:
        with pytest.raises(CommandError) as ei:
            c.call(cmd, **args)
    assert ei.value.code == code and all(w in ei.value.args[0] for w in words), ei.value.args[0]
