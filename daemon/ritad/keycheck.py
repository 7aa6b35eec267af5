"""``ritad --check-config``'s key check: the CURVE server key ritad would load at start exists and is one.

ritad reads the secret from ``$CREDENTIALS_DIRECTORY/ritad-server.key_secret`` (systemd's
``LoadCredential=``) when present, else from ``<data_dir>/keys/server.key_secret``. A check run
from a shell has no credentials directory, so the installed unit's ``LoadCredential=`` source
counts too: that is the file systemd will hand over.
"""
from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Mapping

from daemon.bus.auth import CREDENTIAL_NAME, load_keypair
from daemon.ritad.config import Config

UNIT = Path("/etc/systemd/system/ritad.service")


def _unit_credential(unit: Path) -> Path | None:
    try:
        text = unit.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    m = re.search(rf"^\s*LoadCredential\s*=\s*{re.escape(CREDENTIAL_NAME)}:(\S+)\s*$", text, re.MULTILINE)
    return Path(m.group(1)) if m else None


def server_key_candidates(cfg: Config, env: Mapping[str, str] = os.environ, unit: Path = UNIT) -> list[Path]:
    """Where the server key may be, in ritad's order of preference."""
    out = []
    if env.get("CREDENTIALS_DIRECTORY"):
        out.append(Path(env["CREDENTIALS_DIRECTORY"]) / CREDENTIAL_NAME)
    if (cred := _unit_credential(unit)) is not None:
        out.append(cred)
    return out + [Path(cfg.daemon.data_dir) / "keys" / "server.key_secret"]


def key_problems(cfg: Config, env: Mapping[str, str] = os.environ,
                 unit: Path = UNIT) -> tuple[list[str], list[str]]:
    """(errors, warnings) about the configured key files; nothing to check without CURVE."""
    if not cfg.security.curve:
        return [], []
    candidates = server_key_candidates(cfg, env, unit)
    found = next((p for p in candidates if p.exists()), None)
    errors, warnings = [], []
    if found is None:
        keys_dir = candidates[-1].parent
        errors.append(f"security.curve is on but the server key file {candidates[-1]} does not exist "
                      f"(looked in: {', '.join(map(str, candidates))}): create it with "
                      f"`ritactl keys init --server --dir {keys_dir}`")
    else:
        try:
            load_keypair(found)
        except (OSError, ValueError) as exc:
            errors.append(f"server key {found}: {exc}")
    auth = Path(cfg.security.authorized_keys_dir)
    auth = auth if auth.is_absolute() else Path(cfg.daemon.data_dir) / auth
    if not auth.is_dir():
        warnings.append(f"security.authorized_keys_dir {auth} does not exist yet: no CURVE client can "
                        f"connect until a key is allowed "
                        f"(`ritactl keys allow FILE.key --name NAME --role operator`)")
    return errors, warnings
