"""CURVE keys and the ZAP allow-list for the TCP endpoints.

Every ``tcp://`` endpoint is a CURVE server; the ZAP authenticator (a pyzmq
``ThreadAuthenticator``) is started *before* any bind, because a CURVE server
without a running authenticator accepts any key. Client public keys live one per
file in the authorized-keys directory (``<name>.key``, a ZeroMQ certificate with the
key's role, see :mod:`daemon.bus.roles`); the directory is re-read whenever it changes,
so ``ritactl keys allow/role/revoke`` takes effect without a restart: ZAP checks new
connections, the command server every request. ``ipc://`` endpoints stay plain: the
file system guards them.

Every refused attempt is logged with the client's key (or "plaintext") and peer
address: unknown keys by the ZAP handler, which knows both; clients without CURVE
(or with a broken handshake) by a monitor on each CURVE socket, since they never
reach ZAP. Repeats from one peer within a minute are counted into one line, because
a refused client reconnects every 100 ms.

The server's secret key comes from the systemd credentials directory
(``$CREDENTIALS_DIRECTORY/ritad-server.key_secret``) when present, else from
``<data_dir>/keys/server.key_secret``. Secret files are written with mode 0600.
"""
from __future__ import annotations

import logging
import os
import socket
import threading
import time
from pathlib import Path

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator
from zmq.utils.monitor import parse_monitor_message

from daemon.bus.repeatlog import RepeatGate
from daemon.bus.roles import KeyEntry, read_entry

log = logging.getLogger(__name__)

CREDENTIAL_NAME = "ritad-server.key_secret"
ZAP_DOMAIN = "rita"


def is_secure_endpoint(endpoint: str) -> bool:
    """Endpoints that cross the network get CURVE; ipc/inproc stay plain."""
    return endpoint.startswith("tcp://")


def create_keypair(directory: Path, name: str) -> tuple[Path, Path]:
    """Write ``name.key`` (public) and ``name.key_secret`` (0600) into ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    os.chmod(directory, 0o700)
    old = os.umask(0o077)  # pyzmq does not chmod: make the secret private from the start
    try:
        public, secret = zmq.auth.create_certificates(str(directory), name)
    finally:
        os.umask(old)
    os.chmod(secret, 0o600)
    os.chmod(public, 0o644)
    return Path(public), Path(secret)


def load_keypair(path: Path) -> tuple[bytes, bytes]:
    """(public, secret) z85 keys from a ``*.key_secret`` file; refuses group/world-readable secrets."""
    mode = path.stat().st_mode & 0o077
    if mode:
        raise PermissionError(f"{path} is readable by others (mode {oct(path.stat().st_mode & 0o777)}): "
                              f"chmod 600 it")
    public, secret = zmq.auth.load_certificate(str(path))
    if secret is None:
        raise ValueError(f"{path} holds no secret key")
    return public, secret


def load_public(path: Path) -> bytes:
    public, _ = zmq.auth.load_certificate(str(path))
    return public


class RefusalLog:
    """One WARNING per refused (who, peer host) per ``window_s``; repeats are counted into the next line."""

    def __init__(self, window_s: float = 60.0) -> None:
        self.window_s = window_s
        self._lock = threading.Lock()
        self._gate: RepeatGate[tuple[str, str]] = RepeatGate(window_s)  # (who, host)
        self.count = 0

    def refused(self, who: str, peer: str, why: str) -> None:
        host = peer.rsplit(":", 1)[0] if ":" in peer else peer  # repeats come from new ports
        with self._lock:
            self.count += 1
            repeats = self._gate.admit((who, host))
        if repeats is None:
            return
        more = f" ({repeats} more attempt(s) in the last {self.window_s:g} s)" if repeats else ""
        log.warning("refused %s client from %s: %s%s", who, peer, why, more)


class KeyRing:
    """The allow-list: public keys with their roles in a directory, re-read when the directory changes.

    ZAP asks it at every CURVE handshake; the command server asks it again at every
    request (``lookup``), so a revocation or a new role applies to open connections too.
    A request costs one stat of the folder: ``ritactl keys`` and ``keys.*`` replace or
    remove files, which changes the folder's mtime. The full scan (every file's stat)
    runs when that mtime changed, while it is too recent to tell two changes in one
    clock tick apart, and at least every ``rescan_s`` (a file edited in place).
    """

    RACY_NS = 2_000_000_000  # folder changed this close before a scan: the next request scans again

    def __init__(self, directory: Path, refusals: RefusalLog | None = None, rescan_s: float = 1.0) -> None:
        self.directory = Path(directory)
        self.refusals = refusals or RefusalLog()
        self.peer = "?"  # the address of the ZAP request being answered (set by _Authenticator)
        self.rescan_ns = int(rescan_s * 1e9)
        self._lock = threading.Lock()
        self._stamp: tuple[int, int, int] | None = None
        self._keys: dict[bytes, KeyEntry] = {}
        self._dir_stamp: tuple[int, int] | None = None
        self._scanned_ns = 0

    def _unchanged(self) -> bool:
        """True when one stat of the folder shows nothing can have changed since the last scan."""
        try:
            st = self.directory.stat()
            dir_stamp = (st.st_mtime_ns, st.st_ino)
        except FileNotFoundError:
            dir_stamp = (0, 0)
        now = time.time_ns()
        if (dir_stamp == self._dir_stamp and self._scanned_ns - dir_stamp[0] > self.RACY_NS
                and now - self._scanned_ns < self.rescan_ns):
            return True
        self._dir_stamp, self._scanned_ns = dir_stamp, now
        return False

    def _reload(self) -> None:
        if self._unchanged():
            return
        try:
            st = self.directory.stat()
            files = sorted(self.directory.glob("*.key"))
            stats = [f.stat() for f in files]
            # a role change rewrites one file: its mtime and inode change even within one clock tick
            stamp = (st.st_mtime_ns, sum(s.st_mtime_ns for s in stats), sum(s.st_ino for s in stats))
        except FileNotFoundError:
            stamp, files = (0, 0, 0), []
        if stamp == self._stamp:
            return
        keys = {}
        for f in files:
            try:
                entry = read_entry(f)
                keys[entry.public] = entry
            except (OSError, ValueError) as exc:  # a broken file must not open or close the door for others
                log.warning("ignoring unusable key file %s: %s", f, exc)
        self._keys, self._stamp = keys, stamp
        log.info("allow-list %s: %d key(s) (%s)", self.directory, len(keys),
                 ", ".join(f"{e.name}: {e.role}" for e in keys.values()) or "none")

    def names(self) -> dict[bytes, str]:
        with self._lock:
            self._reload()
            return {k: e.name for k, e in self._keys.items()}

    def lookup(self, public: bytes) -> KeyEntry | None:
        """The entry of a z85 public key, or None when it is not (or no longer) allowed."""
        with self._lock:
            self._reload()
            return self._keys.get(public)

    def callback(self, domain: str, key: bytes) -> bool:
        """Called by the authenticator for every CURVE handshake."""
        allowed = self.lookup(key) is not None
        if not allowed:
            self.refusals.refused(f"CURVE key {key.decode(errors='replace')}", self.peer,
                                  f"unknown key, not in the allow-list {self.directory}")
        return allowed


class _Authenticator(ThreadAuthenticator):
    """pyzmq's authenticator, telling the key ring the peer address of each request (for the log)."""

    def __init__(self, ctx: zmq.Context, keyring: KeyRing) -> None:
        super().__init__(ctx, log=logging.getLogger("daemon.zap"))
        self.keyring = keyring

    async def handle_zap_message(self, msg: list[bytes]) -> None:
        # frames: version, request id, domain, address, identity, mechanism, credentials...
        self.keyring.peer = msg[3].decode(errors="replace") if len(msg) > 3 else "?"
        await super().handle_zap_message(msg)


#: a connection libzmq closed before this thread could read its address (fast local clients)
UNKNOWN_PEER = "an unknown address (closed before it could be read)"


def _peer_of(fd: int) -> str:
    """host:port of an accepted TCP connection's file descriptor."""
    try:
        dup = os.dup(fd)  # the socket object below owns (and closes) only this copy
    except OSError:
        return UNKNOWN_PEER
    try:
        s = socket.socket(fileno=dup)  # the family is read from the descriptor
    except OSError:
        os.close(dup)
        return UNKNOWN_PEER
    try:
        host, port = s.getpeername()[:2]
        return f"{host}:{port}"
    except (OSError, ValueError):
        return UNKNOWN_PEER
    finally:
        s.close()


class HandshakeWatch(threading.Thread):
    """Logs connections a CURVE socket refused before ZAP was asked: plaintext clients, wrong keys.

    Such a client either fails the ZMTP greeting (mechanism mismatch) or hangs up
    before the handshake completes, depending on which side reads the other's greeting
    first; libzmq may report nothing but the disconnect. So every accepted connection
    is "handshaking" until a HANDSHAKE_SUCCEEDED; one that disconnects while still
    handshaking was refused. Success events carry no descriptor: when two handshakes
    overlap, both are dropped from watch (a refusal may then go unlogged). A failure
    event is followed by its connection's DISCONNECTED (same I/O thread, in order).
    ZAP refusals are logged by the key ring, which knows the key.
    """

    EVENTS = zmq.EVENT_ACCEPTED | zmq.EVENT_HANDSHAKE_SUCCEEDED | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL \
        | zmq.EVENT_HANDSHAKE_FAILED_AUTH | zmq.EVENT_DISCONNECTED | zmq.EVENT_MONITOR_STOPPED

    def __init__(self, ctx: zmq.Context, sock: zmq.Socket, refusals: RefusalLog) -> None:
        super().__init__(name="handshake-watch", daemon=True)
        addr = f"inproc://handshake-watch-{id(sock):x}"
        sock.monitor(addr, self.EVENTS)
        self.mon = ctx.socket(zmq.PAIR)
        self.mon.setsockopt(zmq.LINGER, 0)
        self.mon.connect(addr)
        self.refusals = refusals
        self.stopping = threading.Event()
        self._handshaking: dict[int, str] = {}  # fd -> peer address
        self._failed: str | None = None

    def run(self) -> None:
        try:
            while not self.stopping.is_set():
                if not self.mon.poll(200, zmq.POLLIN):
                    continue
                ev = parse_monitor_message(self.mon.recv_multipart())
                if not self.on_event(ev["event"], ev["value"]):
                    break
        finally:
            self.mon.close(linger=0)

    def on_event(self, kind: int, value: int) -> bool:
        """One monitor event (``value``: the socket's fd, or the handshake's error code); False: stop."""
        if kind == zmq.EVENT_MONITOR_STOPPED:
            return False
        if kind == zmq.EVENT_ACCEPTED:
            self._handshaking[value] = _peer_of(value)
        elif kind == zmq.EVENT_HANDSHAKE_SUCCEEDED:
            self._handshaking.clear()  # exactly one was pending in the normal case; else: ambiguous
        elif kind == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
            self._failed = "zap"  # the key ring has logged it, with the key
        elif kind == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL:
            mismatch = value == zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH
            self._failed = "plaintext" if mismatch else f"{value:#x}"
        elif kind == zmq.EVENT_DISCONNECTED:
            peer, failed = self._handshaking.pop(value, None), self._failed
            self._failed = None
            if failed == "plaintext":
                self.refusals.refused("plaintext", peer or UNKNOWN_PEER, "this endpoint requires CURVE keys")
            elif failed not in (None, "zap"):
                self.refusals.refused("unauthenticated", peer or UNKNOWN_PEER, f"broken handshake ({failed})")
            elif failed is None and peer is not None:
                self.refusals.refused("unauthenticated", peer,
                                      "hung up before completing the CURVE handshake "
                                      "(no keys, or the wrong server key)")
        return True


class Security:
    """Server keys + authenticator; ``apply(sock)`` makes a socket a CURVE server."""

    def __init__(self, keys_dir: Path, authorized_dir: Path) -> None:
        cred = os.environ.get("CREDENTIALS_DIRECTORY")
        cred_file = Path(cred) / CREDENTIAL_NAME if cred else None
        secret_file = cred_file if cred_file and cred_file.exists() else keys_dir / "server.key_secret"
        if not secret_file.exists():
            raise FileNotFoundError(f"CURVE is on but there is no server key at {secret_file}: "
                                    f"create one with `ritactl keys init --server --dir {keys_dir}`")
        self.public, self.secret = load_keypair(secret_file)
        self.refusals = RefusalLog()
        self.keyring = KeyRing(authorized_dir, self.refusals)
        self.auth: ThreadAuthenticator | None = None
        self._ctx: zmq.Context | None = None
        self._watches: list[HandshakeWatch] = []
        log.info("CURVE on: server key %s (from %s), allow-list %s", self.public.decode(), secret_file,
                 authorized_dir)

    def start(self, ctx: zmq.Context) -> None:
        """Start ZAP before anything binds (a CURVE server without ZAP accepts any key)."""
        self._ctx = ctx
        self.auth = _Authenticator(ctx, self.keyring)
        self.auth.start()
        self.auth.configure_curve_callback(domain=ZAP_DOMAIN, credentials_provider=self.keyring)

    def apply(self, sock: zmq.Socket) -> None:
        if self.auth is None or self._ctx is None:
            raise RuntimeError("Security.start() must run before any CURVE socket is bound")
        sock.curve_secretkey = self.secret
        sock.curve_publickey = self.public
        sock.curve_server = True
        sock.zap_domain = ZAP_DOMAIN.encode()
        watch = HandshakeWatch(self._ctx, sock, self.refusals)  # before bind: no connection goes unseen
        watch.start()
        self._watches.append(watch)

    def stop(self) -> None:
        """After the CURVE sockets are closed (their monitors then stop by themselves)."""
        for w in self._watches:
            w.stopping.set()
            w.join(2.0)
        self._watches = []
        if self.auth is not None:
            self.auth.stop()
            self.auth = None
