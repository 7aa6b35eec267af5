"""Package faces: each package's public names, no reach into another package's private names, and
the bus's vocabularies (roles, device kinds, topics) defined once (daemon/bus/names.py)."""
from __future__ import annotations

import ast
import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

from daemon.bus.names import KINDS, ROLES, Topic

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("daemon.bus", "daemon.compute", "daemon.ritad", "daemon.ctl", "daemon.worker", "daemon.console",
            "drivers", "calibration", "fakes")


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_name_of_a_package_resolves(package):
    module = importlib.import_module(package)
    assert module.__all__, package
    for name in module.__all__:
        assert getattr(module, name) is not None, f"{package}.{name}"
    with pytest.raises(AttributeError, match="has no attribute 'nope'"):
        getattr(module, "nope")


def test_the_faces_load_nothing_heavy():
    """ritactl's packages keep starting without numpy or OpenCV: a face imports on first use."""
    code = ("import sys, daemon.bus, daemon.ctl, daemon.console, drivers; "
            "from daemon.bus import Client, Topic; "
            "print(sorted(m for m in ('numpy', 'cv2', 'harvesters', 'serial') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]"


def _package_of(module: str, is_pkg: bool) -> str:
    return module if is_pkg else module.rpartition(".")[0]


def test_no_module_imports_another_packages_private_names():
    bad = []
    for top in ("daemon", "drivers", "calibration", "fakes"):
        for path in sorted((ROOT / top).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            is_pkg = parts[-1] == "__init__"
            mine = _package_of(".".join(parts[:-1] if is_pkg else parts), is_pkg)
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    theirs = node.module if (ROOT / node.module.replace(".", "/")).is_dir() else \
                        node.module.rpartition(".")[0]
                    for a in node.names:
                        if a.name.startswith("_") and not a.name.startswith("__") and theirs != mine:
                            bad.append(f"{path.relative_to(ROOT)}: from {node.module} import {a.name}")
    assert bad == []


def test_every_topic_published_or_emitted_is_a_declared_topic():
    """Drivers sit below the bus library and emit topics as text: each must be one of Topic."""
    literal = re.compile(r"""(?:emit|publish|_publish)\(\s*["']([a-z_.]+)["']""")
    used = set()
    for top in ("daemon", "drivers", "fakes"):
        for path in (ROOT / top).rglob("*.py"):
            used |= set(literal.findall(path.read_text(encoding="utf-8")))
    assert used, "the pattern found no topic at all"
    assert used <= {t.value for t in Topic}, used - {t.value for t in Topic}
    documented = (ROOT / "docs" / "protocol.md").read_text(encoding="utf-8")
    assert all(f"| `{t.value}` |" in documented for t in Topic if t is not Topic.CAMERA_FRAME)


def test_roles_and_kinds_come_from_one_place():
    from daemon.bus.command_table import COMMANDS
    from daemon.ritad import config, registry

    assert ROLES == ("viewer", "operator", "admin")
    assert {c.role for c in COMMANDS.values()} <= set(ROLES)
    assert tuple(config.Config().device_urls()) == KINDS
    assert set(registry.ADAPTERS) == set(KINDS)
