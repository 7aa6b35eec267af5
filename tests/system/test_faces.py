"""Packages: no faces (names imported from their modules), no reach into another package's private
names, and the bus's vocabularies (roles, device kinds, topics) defined once (daemon/bus/names.py)."""
from __future__ import annotations

import ast
import re
from pathlib import Path

from daemon.bus.names import KINDS, ROLES, Topic

ROOT = Path(__file__).resolve().parents[2]
TOPS = ("daemon", "drivers", "calibration", "fakes")


def face_lines(source: str) -> list[int]:
    """Lines of a package's ``__init__`` that make it a face: names imported from our modules (a
    re-export) or a module ``__getattr__`` (a lazy one). Code the package defines itself is not one."""
    bad = []
    for node in ast.walk(ast.parse(source)):
        ours = isinstance(node, ast.ImportFrom) and (node.level > 0
                                                     or (node.module or "").split(".")[0] in TOPS)
        ours |= isinstance(node, ast.Import) and any(a.name.split(".")[0] in TOPS for a in node.names)
        lazy = isinstance(node, ast.FunctionDef) and node.name == "__getattr__"
        if ours or lazy:
            bad.append(node.lineno)
    return sorted(bad)


def test_packages_have_no_faces():
    """A name is imported from the module that defines it (``from daemon.bus.client import Client``):
    no package re-exports names, so a module's names are listed once, in the module, and importing a
    package loads nothing else (ritactl starts without numpy or OpenCV: tests/daemon/ctl/test_ctl.py).
    A package may define code of its own in ``__init__`` (daemon/ctl/foxglove_schemas: its data files)."""
    bad = [f"{p.relative_to(ROOT)}:{n}" for top in TOPS for p in sorted((ROOT / top).rglob("__init__.py"))
           for n in face_lines(p.read_text(encoding="utf-8"))]
    assert bad == []


def test_a_face_is_caught():
    assert face_lines('"""Doc."""\n\n__version__ = "1"\nimport json\n\n'
                      'def schema():\n    return json\n') == []
    assert face_lines('"""Doc."""\nfrom daemon.bus.client import Client\n__all__ = ["Client"]\n') == [2]
    assert face_lines("from .client import Client\nimport drivers.base\n") == [1, 2]
    assert face_lines("def __getattr__(name):\n    return name\n") == [1]


def _package_of(module: str, is_pkg: bool) -> str:
    return module if is_pkg else module.rpartition(".")[0]


def test_no_module_imports_another_packages_private_names():
    bad = []
    for top in TOPS:
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
