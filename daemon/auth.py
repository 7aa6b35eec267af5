"""CURVE keys and the ZAP allow-list for the TCP endpoints.

Every ``tcp://`` endpoint is a CURVE server; the ZAP authenticator (a pyzmq
``ThreadAuthenticator``) is started *before* any bind, because a CURVE server
without a running authenticator accepts any key. Client public keys live one per
file in the authorized-keys directory (``<name>.key``, the format of
``zmq.auth.create_certificates``); the directory is re-read whenever it changes, so
``ritactl keys allow/revoke`` takes effect for the next connection without a
restart. ``ipc://`` endpoints stay plain: the file system guards them.

The server's secret key comes from the systemd credentials directory
(``$CREDENTIALS_DIRECTORY/ritad-server.key_secret``) when present, else from
``<data_dir>/keys/server.key_secret``. Secret files are written with mode 0600.
"""
from __future__ import annotations

import logging
import os
import threading
from pathlib import Path

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

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


class KeyRing:
    """The allow-list: public keys in a directory, re-read when the directory changes."""

    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)
        self._lock = threading.Lock()
        self._stamp: tuple[int, int] | None = None
        self._keys: dict[bytes, str] = {}

    def _reload(self) -> None:
        try:
            st = self.directory.stat()
            files = sorted(self.directory.glob("*.key"))
            stamp = (st.st_mtime_ns, sum(f.stat().st_mtime_ns for f in files))
        except FileNotFoundError:
            stamp, files = (0, 0), []
        if stamp == self._stamp:
            return
        keys = {}
        for f in files:
            try:
                keys[load_public(f)] = f.stem
            except Exception as exc:  # a broken key file must not open or close the door for others
                log.warning("ignoring unreadable key file %s: %s", f, exc)
        self._keys, self._stamp = keys, stamp
        log.info("allow-list %s: %d key(s)", self.directory, len(keys))

    def names(self) -> dict[bytes, str]:
        with self._lock:
            self._reload()
            return dict(self._keys)

    def callback(self, domain: str, key: bytes) -> bool:
        """Called by the authenticator for every CURVE handshake."""
        allowed = key in self.names()
        if not allowed:
            log.warning("refused CURVE client with unknown key %s", key.decode(errors="replace"))
        return allowed


class Security:
    """Server keys + authenticator; ``apply(sock)`` makes a socket a CURVE server."""

    def __init__(self, keys_dir: Path, authorized_dir: Path) -> None:
        cred = os.environ.get("CREDENTIALS_DIRECTORY")
        cred_file = Path(cred) / CREDENTIAL_NAME if cred else None
        secret_file = cred_file if cred_file and cred_file.exists() else keys_dir / "server.key_secret"
        if not secret_file.exists():
            raise FileNotFoundError(f"CURVE is on but there is no server key at {secret_file}: create one with "
                                    f"`ritactl keys init --server --dir {keys_dir}`")
        self.public, self.secret = load_keypair(secret_file)
        self.keyring = KeyRing(authorized_dir)
        self.auth: ThreadAuthenticator | None = None
        log.info("CURVE on: server key %s (from %s), allow-list %s", self.public.decode(), secret_file,
                 authorized_dir)

    def start(self, ctx: zmq.Context) -> None:
        """Start ZAP before anything binds (a CURVE server without ZAP accepts any key)."""
        self.auth = ThreadAuthenticator(ctx, log=logging.getLogger("daemon.zap"))
        self.auth.start()
        self.auth.configure_curve_callback(domain=ZAP_DOMAIN, credentials_provider=self.keyring)

    def apply(self, sock: zmq.Socket) -> None:
        if self.auth is None:
            raise RuntimeError("Security.start() must run before any CURVE socket is bound")
        sock.curve_secretkey = self.secret
        sock.curve_publickey = self.public
        sock.curve_server = True
        sock.zap_domain = ZAP_DOMAIN.encode()

    def stop(self) -> None:
        if self.auth is not None:
            self.auth.stop()
            self.auth = None
