"""``ritactl keys``: CURVE key files for the laptop and the robot's allow-list.

On the laptop: ``ritactl keys init`` makes ``client.key`` + ``client.key_secret`` in the
keys folder (default ``~/.config/rita``, or ``$RITA_KEYS``); copy the robot's
``server.key`` there too. On the robot: ``ritactl keys init --server --dir
/var/lib/ritad/keys`` once, then ``ritactl keys allow laptop.key --name alice`` for
each operator; ``revoke`` takes effect for the next connection, without a restart.
Only pyzmq is needed (no OpenCV/numpy).
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path
from typing import Any

DEFAULT_AUTH_DIR = "/var/lib/ritad/authorized_keys"


def default_keys_dir() -> Path:
    return Path(os.environ.get("RITA_KEYS") or Path.home() / ".config" / "rita")


def client_curve(endpoint: str, keys_dir: Path | None = None) -> dict[str, bytes] | None:
    """CURVE client keys for a tcp endpoint when the key files exist, else None (plain)."""
    if not endpoint.startswith("tcp://"):
        return None
    d = keys_dir or default_keys_dir()
    secret, server = d / "client.key_secret", d / "server.key"
    if not (secret.exists() and server.exists()):
        return None
    from daemon.auth import load_keypair, load_public

    public, sec = load_keypair(secret)
    return {"public": public, "secret": sec, "server": load_public(server)}


def cmd_keys(c: Any, a: argparse.Namespace) -> int:
    from daemon.auth import create_keypair, load_public

    if a.action == "init":
        d = Path(a.dir) if a.dir else default_keys_dir()
        name = "server" if a.server else (a.name or "client")
        if (d / f"{name}.key_secret").exists() and not a.force:
            print(f"ritactl: {d / (name + '.key_secret')} exists (use --force to replace it)", file=sys.stderr)
            return 1
        public, secret = create_keypair(d, name)
        print(f"created {public} (public, share it) and {secret} (secret, mode 600)")
        if not a.server:
            print(f"now copy the robot's server.key into {d} and have the robot allow {public}")
        return 0
    auth = Path(a.dir or DEFAULT_AUTH_DIR)
    if a.action == "allow":
        if not a.file:
            print("ritactl: keys allow needs the client's public key file", file=sys.stderr)
            return 2
        src = Path(a.file)
        try:
            key = load_public(src)
        except Exception as exc:
            print(f"ritactl: {src} is not a CURVE public key file: {exc}", file=sys.stderr)
            return 1
        auth.mkdir(parents=True, exist_ok=True)
        dest = auth / f"{a.name or src.stem}.key"
        tmp = dest.with_suffix(".tmp")
        shutil.copyfile(src, tmp)
        tmp.replace(dest)
        print(f"allowed {dest.stem}: {key.decode()}")
        return 0
    if a.action == "revoke":
        if not a.name:
            print("ritactl: keys revoke needs --name", file=sys.stderr)
            return 2
        target = auth / f"{a.name}.key"
        if not target.exists():
            print(f"ritactl: no key named {a.name!r} in {auth}", file=sys.stderr)
            return 1
        target.unlink()
        print(f"revoked {a.name} (new connections with that key are refused now)")
        return 0
    if a.action == "list":
        for f in sorted(auth.glob("*.key")):
            try:
                print(f"{f.stem:20s} {load_public(f).decode()}")
            except Exception as exc:
                print(f"{f.stem:20s} unreadable: {exc}")
        return 0
    return 2


def add_parser(sub: Any) -> None:
    p = sub.add_parser("keys", help="CURVE keys: init | allow FILE | revoke --name N | list")
    p.add_argument("action", choices=["init", "allow", "revoke", "list"])
    p.add_argument("file", nargs="?", help="allow: the client's public key file")
    p.add_argument("--dir", help=f"keys folder (init; default {default_keys_dir()}) or allow-list "
                                 f"(allow/revoke/list; default {DEFAULT_AUTH_DIR})")
    p.add_argument("--name", help="init: key name; allow/revoke: the client's name in the allow-list")
    p.add_argument("--server", action="store_true", help="init: the robot's server key pair")
    p.add_argument("--force", action="store_true", help="init: replace an existing key pair")
    p.set_defaults(fn=cmd_keys, offline=True)
