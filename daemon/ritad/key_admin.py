"""``keys.*`` bus commands: an admin key manages the allow-list from a laptop.

The same files as ``ritactl keys`` on the robot (:mod:`daemon.bus.roles`), written in
the storage thread (atomic replace, so a crash never leaves half a key file). The key
ring re-reads the directory at the next handshake or request: no restart. Every change
is logged with the admin key that made it.
"""
from __future__ import annotations

import logging
from concurrent.futures import Future
from pathlib import Path
from typing import Any, Callable

from daemon.bus import roles
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.ritad.server import Request

log = logging.getLogger(__name__)


def _text(req: Request, name: str, default: str | None = None) -> str:
    value = req.args.get(name, default)
    if value is None:
        raise CommandError(ErrorCode.BAD_ARGS, f"{req.cmd}: missing argument {name!r}")
    if not isinstance(value, str):
        raise CommandError(ErrorCode.BAD_ARGS, f"{req.cmd}: argument {name!r} must be str, got {value!r}")
    return value


def _entry_dict(e: roles.KeyEntry) -> dict[str, str]:
    return {"name": e.name, "role": e.role, "public_key": e.public.decode()}


def _guard(req: Request, fn: Callable[[], Any]) -> Any:
    """Run a file change; bad values are ``bad_args``, a missing entry ``not_found``."""
    try:
        result = fn()
    except LookupError as exc:
        raise CommandError(ErrorCode.NOT_FOUND, f"{req.cmd}: {exc.args[0]}") from None
    except ValueError as exc:
        raise CommandError(ErrorCode.BAD_ARGS, f"{req.cmd}: {exc}") from None
    log.warning("allow-list changed: %s %s by %s", req.cmd, {k: req.args.get(k) for k in ("name", "role")},
                req.peer)
    return result


def key_handlers(auth_dir: Path, submit: Callable[[Callable[[], Any]], Future]
                 ) -> dict[str, Callable[[Request], Any]]:
    """Handlers of keys.list, keys.allow, keys.role, keys.revoke on the allow-list ``auth_dir``.

    ``submit`` runs file work off the server thread (the daemon's storage executor).
    """

    def keys_list(req: Request) -> Any:
        def run() -> Any:
            entries, broken = roles.list_entries(auth_dir)
            return {"dir": str(auth_dir), "keys": [_entry_dict(e) for e in entries], "unreadable": broken}

        return submit(run)

    def keys_allow(req: Request) -> Any:
        name, public = _text(req, "name"), _text(req, "public_key").encode()
        role = _text(req, "role", roles.DEFAULT_ROLE)
        return submit(lambda: _entry_dict(_guard(req, lambda: roles.write_entry(auth_dir, name, public,
                                                                                          role))))

    def keys_role(req: Request) -> Any:
        name, role = _text(req, "name"), _text(req, "role")
        return submit(lambda: _entry_dict(_guard(req, lambda: roles.set_role(auth_dir, name, role))))

    def keys_revoke(req: Request) -> Any:
        name = _text(req, "name")
        return submit(lambda: _guard(req, lambda: roles.revoke(auth_dir, name)) or {"revoked": name})

    return {"keys.list": keys_list, "keys.allow": keys_allow, "keys.role": keys_role,
            "keys.revoke": keys_revoke}
