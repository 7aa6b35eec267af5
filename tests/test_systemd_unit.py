"""The unit file passes `systemd-analyze verify` with empty stderr and stays hardened."""
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

UNIT = Path(__file__).resolve().parents[1] / "systemd" / "ritad.service"
ANALYZE = shutil.which("systemd-analyze")


@pytest.fixture
def unit_copy(tmp_path):
    """The unit with ExecStart pointing at this venv's ritad (verify checks the binary exists)."""
    ritad = Path(sys.executable).parent / "ritad"
    if not ritad.exists():
        ritad = Path(sys.executable)
    text = re.sub(r"^ExecStart=\S+", f"ExecStart={ritad}", UNIT.read_text(), flags=re.M)
    out = tmp_path / "ritad.service"
    out.write_text(text)
    return out


def test_unit_has_the_required_settings():
    text = UNIT.read_text()
    for needle in ("Type=notify", "WatchdogSec=", "Restart=on-failure", "StartLimitBurst=", "StateDirectory=",
                   "ConfigurationDirectory=", "ProtectSystem=strict", "ProtectHome=", "PrivateTmp=yes",
                   "NoNewPrivileges=yes", "RestrictAddressFamilies=", "SupplementaryGroups=dialout"):
        assert needle in text, needle


def test_verify_is_clean(unit_copy):
    assert ANALYZE, "systemd-analyze missing: .ci/run installs the systemd package"
    res = subprocess.run([ANALYZE, "verify", str(unit_copy)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and res.stderr.strip() == "", res.stderr


def test_security_exposure_at_most_3(unit_copy):
    assert ANALYZE
    res = subprocess.run([ANALYZE, "security", "--offline=true", "--no-pager", str(unit_copy)],
                         capture_output=True, text=True, timeout=60)
    m = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", res.stdout + res.stderr)
    assert m, res.stdout[-2000:] + res.stderr[-2000:]
    assert float(m.group(1)) <= 3.0, m.group(0)
