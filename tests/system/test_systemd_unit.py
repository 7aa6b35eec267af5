"""The unit file passes `systemd-analyze verify` with empty stderr and stays hardened."""
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
UNIT = ROOT / "systemd" / "ritad.service"
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


def test_the_serial_port_group_is_not_lost_in_a_private_user_namespace():
    # PrivateUsers=yes leaves SupplementaryGroups= unmapped (systemd issue #41994): the port would not open
    text = UNIT.read_text()
    assert re.search(r"^SupplementaryGroups=.*dialout", text, re.M)
    assert not re.search(r"^PrivateUsers=(yes|true|1|on|self)\s*$", text, re.M)


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


OPS = ROOT / "docs" / "operations.md"


def unit_value(key: str) -> str:
    values = re.findall(rf"^{key}=(.*)$", UNIT.read_text(), re.M)
    assert len(values) == 1, (key, values)
    return values[0].strip()


def test_documentation_path_is_installed_by_the_documented_steps():
    doc = unit_value("Documentation")
    assert doc.startswith("file://")
    target = Path(doc[len("file://"):])
    assert (ROOT / "docs" / target.name).exists()
    install = OPS.read_text().split("## Install", 1)[1].split("\n## ", 1)[0]
    assert re.search(rf"install -D -m 644 -t {re.escape(str(target.parent))} docs/\*\.md", install), install


def test_credential_and_binary_paths_agree_between_unit_and_docs():
    cred = unit_value("LoadCredential")
    name, source = cred.split(":", 1)
    from daemon.bus.auth import CREDENTIAL_NAME

    assert name == CREDENTIAL_NAME
    ops = OPS.read_text()
    mentioned = set(re.findall(r"LoadCredential=([^`\s]+)", ops))
    assert mentioned == {cred}, mentioned  # every mention in the docs is the unit's line
    # the documented key is where systemd looks
    assert f"keys init --server --dir {Path(source).parent}" in ops
    exec_start = unit_value("ExecStart").split()[0]
    venv_bin = str(Path(exec_start).parent)
    install = ops.split("## Install", 1)[1].split("\n## ", 1)[0]
    assert f"python3 -m venv {Path(venv_bin).parent}" in install
    assert re.search(rf"ln -sf {re.escape(venv_bin)}/ritad {re.escape(venv_bin)}/ritactl /usr/local/bin/",
                     install)


def test_config_errors_are_not_restarted():
    from daemon.ritad.main import RitadExit

    assert unit_value("RestartPreventExitStatus") == str(int(RitadExit.CONFIG))
