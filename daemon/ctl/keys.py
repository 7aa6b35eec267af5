"""``ritactl keys``: CURVE key files for the laptop and the robot's allow-list.

On the laptop: ``ritactl keys init --name bob`` makes ``bob.key`` + ``bob.key_secret``
in the keys folder (``$RITA_KEYS``, else the config folder of
:mod:`daemon.ctl.config`, ``~/.config/rita``); copy the robot's ``server.key`` there
too, and select the key with ``--key bob`` or ``key = "bob"`` in ``ritactl.toml``
(the default name is ``client``). On the robot: ``ritactl keys init --server --dir
/etc/ritad/keys`` once, then ``ritactl keys allow bob.key --name bob --role operator``
for each operator (default role viewer: least privilege); ``role`` and ``revoke`` apply
from the key's next request, without a restart. With ``--bus`` the same actions go to
the daemon's ``keys.*`` commands, which only an admin key may send.

Once keys are configured (a key name, a keys folder or a server key given, or key
files present in the default folder), a tcp endpoint never falls back to plaintext:
a missing or bad file is a :class:`KeyConfigError` naming it. Only pyzmq is needed.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from daemon.ctl.config import ENV_KEYS, KEY_NAME, default_keys_dir
from daemon.ctl.exitcodes import Exit

DEFAULT_AUTH_DIR = "/var/lib/ritad/authorized_keys"
DEFAULT_KEY = "client"


class KeyConfigError(ValueError):
    """CURVE keys were configured but a file is missing or unusable; the message names the file."""


def _configured(d: Path, key_name: str | None, keys_dir: Path | None, server_key: Path | None) -> bool:
    if key_name is not None or keys_dir is not None or server_key is not None or os.environ.get(ENV_KEYS):
        return True
    return (d / f"{DEFAULT_KEY}.key_secret").exists() or (d / "server.key").exists()


def client_curve(endpoint: str, keys_dir: Path | None = None, key_name: str | None = None,
                 server_key: Path | None = None) -> tuple[dict[str, bytes] | None, str | None]:
    """``(curve, key_id)`` for :class:`daemon.bus.client.Client` (``curve=(curve, key_id)`` works too).

    ``curve`` is ``{"public", "secret", "server"}`` from ``KEYS_DIR/NAME.key_secret`` and
    ``server_key`` (default ``KEYS_DIR/server.key``); ``key_id`` is ``"NAME (public key)"``,
    for messages. ``(None, None)`` for ipc endpoints, and for tcp when no keys are
    configured at all (the daemon then decides; a CURVE daemon refuses). Raises
    KeyConfigError naming the file when configured keys are missing or bad.
    """
    if not endpoint.startswith("tcp://"):
        return None, None
    d = Path(keys_dir).expanduser() if keys_dir is not None else default_keys_dir()
    if not _configured(d, key_name, keys_dir, server_key):
        return None, None
    name = key_name or DEFAULT_KEY
    if not KEY_NAME.fullmatch(name):
        raise KeyConfigError(f"key name {name!r} is not a key name (letters, digits, . _ -)")
    secret = d / f"{name}.key_secret"
    server = Path(server_key).expanduser() if server_key is not None else d / "server.key"
    if not secret.exists():
        init = "ritactl keys init" + ("" if name == DEFAULT_KEY else f" --name {name}")
        raise KeyConfigError(f"CURVE key {secret} does not exist: create it with `{init}` "
                             "(then have it allowed on the robot), or choose another with --key NAME")
    if not server.exists():
        raise KeyConfigError(f"the robot's public key {server} does not exist: copy the robot's "
                             f"/etc/ritad/keys/server.key to it")
    from daemon.bus.auth import load_keypair, load_public

    try:
        public, sec = load_keypair(secret)
    except Exception as exc:  # noqa: BLE001 - pyzmq's parser raises several kinds for a mangled file
        raise KeyConfigError(f"CURVE key {secret} is unusable: {exc}") from None
    try:
        server_public = load_public(server)
    except Exception as exc:  # noqa: BLE001
        raise KeyConfigError(f"the robot's public key {server} is unusable: {exc}") from None
    if not server_public:
        raise KeyConfigError(f"{server} holds no public key")
    return {"public": public, "secret": sec, "server": server_public}, f"{name} ({public.decode()})"


def resolve_connection(endpoint: str | None = None, key: str | None = None,
                       keys_dir: str | Path | None = None,
                       config_path: str | Path | None = None) -> dict[str, Any]:
    """Where and how ritactl connects: the command line beats the environment, which beats ritactl.toml.

    Returns ``{"endpoint", "curve", "key_id", "timeout"}`` (``timeout`` None unless the
    config file sets it). Raises CtlConfigError (a bad config file) or KeyConfigError
    (configured keys missing or bad); both are ValueErrors naming the file.
    """
    from daemon.bus.client import DEFAULT_ENDPOINT, ENV_ENDPOINT
    from daemon.ctl.config import load_ctl_config

    cfg = load_ctl_config(config_path)
    ep = endpoint or os.environ.get(ENV_ENDPOINT) or cfg.get("endpoint") or DEFAULT_ENDPOINT
    if keys_dir is None and not os.environ.get(ENV_KEYS):
        keys_dir = cfg.get("keys_dir")
    curve, key_id = client_curve(ep, Path(keys_dir) if keys_dir is not None else None, key or cfg.get("key"),
                                 cfg.get("server_key"))
    return {"endpoint": ep, "curve": curve, "key_id": key_id, "timeout": cfg.get("timeout")}


def _err(msg: str, code: Exit) -> int:
    print(f"ritactl: {msg}", file=sys.stderr)
    return int(code)


def _init_dir(a: argparse.Namespace) -> Path:
    """Where ``keys init`` writes: the folder every other verb reads keys from, chosen the same way.

    --dir, else ritactl's --keys, else $RITA_KEYS, else ritactl.toml's keys_dir (--config's file),
    else the config folder: the key made is the key ``ritactl --keys DIR status`` then uses.
    """
    from daemon.ctl.config import load_ctl_config

    # --keys: ritactl's own option, absent when the keys parser is used alone
    given = a.dir or getattr(a, "keys", None)
    if given:
        return Path(given).expanduser()
    if os.environ.get(ENV_KEYS):
        return default_keys_dir()
    in_config = load_ctl_config(getattr(a, "config", None)).get("keys_dir")
    return Path(in_config).expanduser() if in_config else default_keys_dir()


def _init(a: argparse.Namespace) -> int:
    from daemon.bus.auth import create_keypair

    try:
        d = _init_dir(a)
    except ValueError as exc:  # CtlConfigError: the config file named, and what is wrong in it
        return _err(str(exc), Exit.BAD_INPUT)
    name = "server" if a.server else (a.name or DEFAULT_KEY)
    if not KEY_NAME.fullmatch(name):
        return _err(f"--name {name!r} is not a key name (letters, digits, . _ -)", Exit.USAGE)
    if (d / f"{name}.key_secret").exists() and not a.force:
        return _err(f"{d / (name + '.key_secret')} exists (use --force to replace it)", Exit.BAD_INPUT)
    public, secret = create_keypair(d, name)
    print(f"created {public} (public, share it) and {secret} (secret, mode 600)")
    if not a.server:
        select = ("" if name == DEFAULT_KEY
                  else f"; select this key with --key {name} or key = \"{name}\" in ritactl.toml")
        print(f"now copy the robot's server.key into {d} and have the robot allow {public}{select}")
    return 0


def _public_of(a: argparse.Namespace) -> tuple[bytes, str] | int:
    """(public key, name) from ``keys allow FILE [--name N]``, or the exit code of a bad FILE/name."""
    from daemon.bus.auth import load_public

    if not a.file:
        return _err("keys allow needs the client's public key file (NAME.key)", Exit.USAGE)
    src = Path(a.file).expanduser()
    if not src.is_file():
        return _err(f"{src} does not exist" if not src.exists() else f"{src} is not a file", Exit.BAD_INPUT)
    if src.name.endswith(".key_secret"):
        return _err(f"{src} is a secret key: allow the public one ({src.name[:-len('_secret')]}), the secret "
                    f"never leaves the laptop", Exit.BAD_INPUT)
    try:
        key = load_public(src)
    except Exception as exc:  # noqa: BLE001 - pyzmq's parser raises several kinds for a mangled file
        return _err(f"{src} is not a CURVE public key file: {exc}", Exit.BAD_INPUT)
    name = a.name or src.stem
    if not KEY_NAME.fullmatch(name):
        return _err(f"--name {name!r} is not a key name (letters, digits, . _ -)", Exit.USAGE)
    return key, name


def _show(entries: list[dict[str, str]], unreadable: dict[str, str]) -> None:
    for e in entries:
        print(f"{e['name']:20s} {e['role']:9s} {e['public_key']}")
    for f, why in unreadable.items():
        print(f"{Path(f).stem:20s} unreadable: {why}")


def _local(a: argparse.Namespace, auth: Path) -> int:
    """The allow-list files on this computer (the robot, as root)."""
    from daemon.bus import roles

    try:
        if a.action == "allow":
            got = _public_of(a)
            if isinstance(got, int):
                return got
            e = roles.write_entry(auth, got[1], got[0], a.role or roles.DEFAULT_ROLE)
            print(f"allowed {e.name} as {e.role}: {e.public.decode()}")
        elif a.action == "role":
            e = roles.set_role(auth, a.name, a.role)
            print(f"{e.name} is now {e.role} (from its next request, no restart)")
        elif a.action == "revoke":
            roles.revoke(auth, a.name)
            print(f"revoked {a.name} (refused from its next request or connection, no restart)")
        else:
            if not auth.is_dir():
                return _err(f"{auth} does not exist (no key allowed yet)", Exit.BAD_INPUT)
            entries, broken = roles.list_entries(auth)
            rows = [{"name": e.name, "role": e.role, "public_key": e.public.decode()} for e in entries]
            _show(rows, broken)
    except (LookupError, ValueError) as exc:
        return _err(str(exc.args[0]) if isinstance(exc, LookupError) else str(exc), Exit.BAD_INPUT)
    return Exit.OK


def _remote(c: Any, a: argparse.Namespace) -> int:
    """The daemon's allow-list over the bus (``--bus``; the daemon refuses unless this key is admin)."""
    if a.action == "allow":
        got = _public_of(a)
        if isinstance(got, int):
            return got
        args = {"name": got[1], "public_key": got[0].decode(), **({"role": a.role} if a.role else {})}
        e = c.call("keys.allow", **args)
        print(f"allowed {e['name']} as {e['role']}: {e['public_key']}")
    elif a.action == "role":
        e = c.call("keys.role", name=a.name, role=a.role)
        print(f"{e['name']} is now {e['role']}")
    elif a.action == "revoke":
        print(f"revoked {c.call('keys.revoke', name=a.name)['revoked']}")
    else:
        r = c.call("keys.list")
        _show(r["keys"], r["unreadable"])
    return Exit.OK


def cmd_keys(c: Any, a: argparse.Namespace) -> int:
    if a.action == "init":
        local = "keys init makes files on this computer: drop --bus"
        return _init(a) if c is None else _err(local, Exit.USAGE)
    if a.action in ("revoke", "role") and not a.name:
        return _err(f"keys {a.action} needs --name", Exit.USAGE)
    if a.action == "role" and not a.role:
        return _err("keys role needs --role (viewer, operator or admin)", Exit.USAGE)
    if c is not None:
        return _remote(c, a)
    return _local(a, Path(a.dir or DEFAULT_AUTH_DIR).expanduser())


def _add_action(ksub: Any, action: str, what: str, description: str) -> argparse.ArgumentParser:
    p: argparse.ArgumentParser = ksub.add_parser(action, help=what, description=description)
    p.set_defaults(fn=cmd_keys, offline=True, action=action, file=None, name=None, role=None, server=False,
                   force=False, parser_=p)
    return p


def _bus_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bus", dest="offline", action="store_false",
                   help="change the daemon's allow-list over the bus, with an admin key (--endpoint/--key), "
                        "instead of the files on this computer")


def add_parser(sub: Any) -> None:
    """``keys init|allow|role|revoke|list``: one subcommand each, with its own --help and options."""
    from daemon.bus.command_table import ROLES
    from daemon.bus.roles import DEFAULT_ROLE

    grp = sub.add_parser("keys", help="CURVE keys: init | allow FILE [--role R] | role --name N --role R | "
                                      "revoke --name N | list")
    grp.set_defaults(fn=None, parser_=grp)
    ksub = grp.add_subparsers(title="keys verbs", metavar="ACTION")
    allow_list = f"allow-list folder (default {DEFAULT_AUTH_DIR}; ignored with --bus)"
    p = _add_action(ksub, "init", "make a CURVE key pair on this computer (offline)",
                    "Make NAME.key (public, share it) and NAME.key_secret (mode 600) in the keys folder: "
                    "--dir, else ritactl's --keys, else $RITA_KEYS, else ritactl.toml's keys_dir, else "
                    f"{default_keys_dir()}.")
    p.add_argument("--dir", metavar="DIR", help="keys folder (default: --keys, $RITA_KEYS, ritactl.toml's "
                                                f"keys_dir, else {default_keys_dir()})")
    p.add_argument("--name", metavar="NAME", help=f"key name (default {DEFAULT_KEY})")
    p.add_argument("--server", action="store_true", help="the robot's server key pair (server.key)")
    p.add_argument("--force", action="store_true", help="replace an existing key pair")
    p = _add_action(ksub, "allow", "allow a client's public key, with a role",
                    "Add a client's public key (NAME.key) to the robot's allow-list; it may connect from its "
                    "next request, no restart.")
    p.add_argument("file", metavar="FILE", help="the client's public key file (NAME.key, never the secret)")
    p.add_argument("--name", metavar="NAME",
                   help="the client's name in the allow-list (default: FILE's stem)")
    p.add_argument("--role", choices=ROLES,
                   help=f"what the key may do (default {DEFAULT_ROLE}: watch, not move)")
    p.add_argument("--dir", metavar="DIR", help=allow_list)
    _bus_option(p)
    p = _add_action(ksub, "role", "change an allowed key's role (from its next request)",
                    "Change the role of an allowed key, from its next request, without a restart.")
    p.add_argument("--name", metavar="NAME", required=True, help="the client's name in the allow-list")
    p.add_argument("--role", choices=ROLES, required=True, help="its new role")
    p.add_argument("--dir", metavar="DIR", help=allow_list)
    _bus_option(p)
    p = _add_action(ksub, "revoke", "remove a key from the allow-list (refused from its next request)",
                    "Remove a key from the allow-list: refused from its next request or connection, "
                    "no restart.")
    p.add_argument("--name", metavar="NAME", required=True, help="the client's name in the allow-list")
    p.add_argument("--dir", metavar="DIR", help=allow_list)
    _bus_option(p)
    p = _add_action(ksub, "list", "the allowed keys: NAME ROLE PUBLIC-KEY",
                    "List the allow-list's keys and roles.")
    p.add_argument("--dir", metavar="DIR", help=allow_list)
    _bus_option(p)
