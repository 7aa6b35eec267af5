"""Roles of client keys: which command a caller may send, and the allow-list files that carry the role.

The roles are ordered, ``viewer`` < ``operator`` < ``admin``; each command's role is
``Command.role`` in :mod:`daemon.bus.command_table`, and a caller may send a command
when its own role is at least that one. A name the table does not know needs admin
(fail closed: a handler registered without an entry is never open to everyone).

An allow-list entry is one file ``<name>.key`` in the authorized-keys directory: a
ZeroMQ public certificate whose metadata holds the role::

    metadata
        role = "operator"
    curve
        public-key = "..."

pyzmq's ``load_certificate`` reads only the key, so these stay ordinary certificates.
A file without a role line (allowed before roles existed, or copied by hand) is a
viewer: least privilege, so forgetting ``--role`` never lets a key move the robot.
Writers replace files atomically (temp file + fsync + rename, mode 0644 so the daemon's
user can read what root wrote); readers re-read the directory when it changes, so a
new role or a revocation applies to the next request without a restart.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

from daemon.bus.command_table import COMMANDS, ROLES, Command
from daemon.bus.storage import atomic_write_text

#: ``keys allow`` without ``--role``: may watch, may not move or change anything
DEFAULT_ROLE = "viewer"
#: a key's name in the allow-list (and the laptop's ``NAME.key_secret``)
KEY_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._-]{0,63}")
_Z85 = set("0123456789abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ.-:+=^!/*?&<>()[]{}@%$#")
_ROLE_LINE = re.compile(r"""^\s*role\s*=\s*["']?([^"'\s]*)["']?\s*$""")


def check_role(role: object) -> str:
    """``role`` if it is one of ROLES, else ValueError naming it."""
    if not isinstance(role, str) or role not in ROLES:
        raise ValueError(f"role {role!r} is not one of {', '.join(ROLES)}")
    return role


def required_role(cmd: str, table: Mapping[str, Command] = COMMANDS) -> str:
    """The role a command needs: its entry's in ``table`` (a daemon's, with its plugins'), admin for
    anything the table lacks."""
    entry = table.get(cmd)
    return entry.role if entry is not None else "admin"


def may(role: str, cmd: str, table: Mapping[str, Command] = COMMANDS) -> bool:
    """Whether a caller with ``role`` may send ``cmd`` (an unknown role may send nothing)."""
    return role in ROLES and ROLES.index(role) >= ROLES.index(required_role(cmd, table))


def refusal(cmd: str, role: str, who: str, table: Mapping[str, Command] = COMMANDS) -> str | None:
    """The ``forbidden`` message for ``who`` (e.g. "key bob") sending ``cmd``, or None when allowed."""
    if may(role, cmd, table):
        return None
    return f"{cmd} needs role {required_role(cmd, table)}; {who} is {role}"


@dataclass(frozen=True)
class KeyEntry:
    name: str
    public: bytes  # z85, as ZAP reports it
    role: str


def _check_name(name: object) -> str:
    if not isinstance(name, str) or not KEY_NAME.fullmatch(name):
        raise ValueError(f"key name {name!r} is not a key name (letters, digits, . _ -; at most 64)")
    return name


def read_entry(path: Path) -> KeyEntry:
    """The entry in ``path``; ValueError (naming the file) when it holds no key or a bad role."""
    text = Path(path).read_text(encoding="utf-8", errors="replace")
    public, role = None, None
    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("public-key"):
            public = stripped.split("=", 1)[1].strip(" \t'\"").encode()
        elif (m := _ROLE_LINE.match(line)) is not None:
            role = m.group(1)
    if not public or len(public) != 40:
        raise ValueError(f"{path} holds no CURVE public key")
    try:
        return KeyEntry(Path(path).stem, public, check_role(role or DEFAULT_ROLE))
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def write_entry(directory: Path, name: str, public: bytes, role: str) -> KeyEntry:
    """Allow ``public`` as ``name`` with ``role`` (replacing an entry of that name)."""
    entry = KeyEntry(_check_name(name), public, check_role(role))
    shown = public.decode(errors="replace")
    if len(public) != 40 or not set(shown) <= _Z85:
        raise ValueError(f"public key {shown!r} is not a 40-character z85 CURVE key")
    text = ("#   ZeroMQ CURVE public certificate: a client allowed by ritad, with its role\n"
            f"metadata\n    role = \"{role}\"\ncurve\n    public-key = \"{public.decode()}\"\n")
    atomic_write_text(Path(directory) / f"{name}.key", text, mode=0o644)
    return entry


def entry_path(directory: Path, name: str) -> Path:
    """The file of the entry ``name``; LookupError when there is none."""
    path = Path(directory) / f"{_check_name(name)}.key"
    if not path.is_file():
        raise LookupError(f"no key named {name!r} in {directory}")
    return path


def set_role(directory: Path, name: str, role: str) -> KeyEntry:
    old = read_entry(entry_path(directory, name))
    return write_entry(directory, name, old.public, role)


def revoke(directory: Path, name: str) -> None:
    entry_path(directory, name).unlink()


def list_entries(directory: Path) -> tuple[list[KeyEntry], dict[str, str]]:
    """(entries by name, {file name: why unreadable}); a missing directory is an empty list."""
    entries, broken = [], {}
    for f in sorted(Path(directory).glob("*.key")) if Path(directory).is_dir() else []:
        try:
            entries.append(read_entry(f))
        except (OSError, ValueError) as exc:
            broken[f.name] = str(exc)
    return entries, broken
