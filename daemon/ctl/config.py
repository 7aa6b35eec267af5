"""The laptop's ritactl config file: which robot, which key, where the keys are.

``ritactl.toml`` (all keys optional)::

    endpoint = "tcp://rita-robot:5555"   # the daemon's command endpoint
    key = "bob"                          # use bob.key_secret (from `ritactl keys init --name bob`)
    keys_dir = "~/.config/rita"          # where NAME.key_secret and server.key are
    server_key = "~/.config/rita/rita-robot-server.key"   # default: KEYS_DIR/server.key
    timeout = 5.0                        # seconds to wait for an answer

It is found at ``$RITA_CONFIG`` if set, else ``%APPDATA%\\rita\\ritactl.toml`` on
Windows, else ``$XDG_CONFIG_HOME/rita/ritactl.toml`` (``~/.config/rita/ritactl.toml``).
A missing default file is an empty config; a file named by ``$RITA_CONFIG`` or
``--config`` must exist. The command line beats the environment, which beats the file.
Only the standard library is used (ritactl runs on a bare laptop).
"""
from __future__ import annotations

import os
import re
import sys
from pathlib import Path
from typing import Any

from daemon.bus.roles import KEY_NAME  # key names become file names: one rule, shared with the daemon

ENV_CONFIG = "RITA_CONFIG"
ENV_KEYS = "RITA_KEYS"
FILE_NAME = "ritactl.toml"


class CtlConfigError(ValueError):
    """The config file is unreadable or has a bad key; the message names the file and the key."""


def config_dir() -> Path:
    """The per-user folder for ritactl's config and keys."""
    if sys.platform == "win32" and os.environ.get("APPDATA"):
        return Path(os.environ["APPDATA"]) / "rita"
    xdg = os.environ.get("XDG_CONFIG_HOME")
    return (Path(xdg) if xdg else Path.home() / ".config") / "rita"


def config_path() -> tuple[Path, bool]:
    """(the config file to read, whether it was named explicitly by $RITA_CONFIG)."""
    env = os.environ.get(ENV_CONFIG)
    return (Path(env).expanduser(), True) if env else (config_dir() / FILE_NAME, False)


def default_keys_dir() -> Path:
    return Path(os.environ.get(ENV_KEYS) or config_dir()).expanduser()


def _endpoint(v: Any) -> str:
    if not isinstance(v, str) or not re.fullmatch(r"(tcp://\S+:\d+|ipc://\S+)", v):
        raise ValueError("must be tcp://HOST:PORT or ipc://PATH")
    return v


def _key(v: Any) -> str:
    if not isinstance(v, str) or not KEY_NAME.fullmatch(v):
        raise ValueError("must be a key name (letters, digits, . _ -), "
                         "as given to `ritactl keys init --name`")
    return v


def _path(v: Any) -> Path:
    if not isinstance(v, str) or not v:
        raise ValueError("must be a path (a string)")
    return Path(v).expanduser()


def _timeout(v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v <= 3600:
        raise ValueError("must be a number of seconds in (0, 3600]")
    return float(v)


KEYS = {"endpoint": _endpoint, "key": _key, "keys_dir": _path, "server_key": _path, "timeout": _timeout}


def load_ctl_config(path: str | Path | None = None) -> dict[str, Any]:
    """The checked settings of the config file (only the keys it sets); ``{}`` when the default
    file is missing.

    Raises CtlConfigError naming the file and the bad key, or the file when it cannot
    be read or parsed.
    """
    import tomllib  # Python >= 3.11

    explicit = path is not None
    file, from_env = (Path(path).expanduser(), True) if path is not None else config_path()
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        if explicit or from_env:
            source = "--config" if explicit else f"${ENV_CONFIG}"
            raise CtlConfigError(f"{file} does not exist (named by {source})") from None
        return {}
    except (OSError, UnicodeDecodeError) as exc:
        raise CtlConfigError(f"cannot read {file}: {exc}") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CtlConfigError(f"{file} is not valid TOML: {exc}") from None
    out: dict[str, Any] = {}
    for key, value in raw.items():
        check = KEYS.get(key)
        if check is None:
            raise CtlConfigError(f"{file}: unknown key {key!r} (known: {', '.join(KEYS)})")
        try:
            out[key] = check(value)
        except ValueError as exc:
            raise CtlConfigError(f"{file}: {key} = {value!r} {exc}") from None
    return out
