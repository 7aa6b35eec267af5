"""Import directions: each layer imports only what is below it, and nothing imports in a cycle.

Layers, bottom up: ``calibration`` (pure numpy/OpenCV) and ``drivers`` are leaves;
``daemon.bus`` is the library every program shares; the programs ``daemon.ritad``,
``daemon.ctl`` and ``daemon.worker`` sit on it; ``fakes`` (the simulated world) may use
drivers, calibration and the bus library, and enters ritad only by configuration (a URL
scheme the registry imports by name). Every import counts, also one inside a function.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("calibration", "drivers", "daemon", "fakes")

# layer -> the layers it may import (its own always allowed); the longest prefix names a module's layer
ALLOWED: dict[str, set[str]] = {
    "calibration": set(),
    "drivers": set(),
    "daemon": set(),  # the package root: __version__ only
    "daemon.bus": {"daemon"},
    "daemon.ritad": {"daemon", "daemon.bus", "drivers",
                     "calibration"},  # camera.detect (daemon/ritad/detect.py) runs the product's own detectors
    "daemon.compute": {"daemon", "daemon.bus", "calibration"},  # the computation both programs share
    "daemon.ctl": {"daemon", "daemon.bus", "daemon.compute",  # ritactl recompute and plate survey, on the laptop
                   "daemon.console"},  # ritactl console starts the console program
    "daemon.console": {"daemon", "daemon.bus"},
    "daemon.worker": {"daemon", "daemon.bus", "daemon.compute", "calibration"},
    "fakes": {"daemon", "daemon.bus", "drivers", "calibration"},  # fakes/plugin.py: Command, the station file
    # the demo composes the simulator with the product: it drives ritactl, and its second part recomputes
    # a dataset without compensations as ritactl recompute does; no product module imports it
    "fakes.demo": {"daemon", "daemon.bus", "daemon.ctl", "fakes", "fakes.demo_floor"},
    "fakes.demo_floor": {"daemon", "daemon.bus", "daemon.ctl", "daemon.compute", "fakes"},
}


def layer_of(module: str) -> str:
    best = ""
    for layer in ALLOWED:
        if (module == layer or module.startswith(layer + ".")) and len(layer) > len(best):
            best = layer
    return best


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def project_imports(source: str, module: str, is_pkg: bool) -> set[str]:
    """Every project module ``source`` imports (absolute or relative, top level or in a function)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module.split(".") if is_pkg else module.split(".")[:-1]
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            names = [base] + [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        out.update(n for n in names if n.split(".")[0] in PACKAGES)
    return out


def violations(modules: dict[str, tuple[str, bool]]) -> list[str]:
    bad = []
    for mod, (source, is_pkg) in sorted(modules.items()):
        mine = layer_of(mod)
        for imp in sorted(project_imports(source, mod, is_pkg)):
            theirs = layer_of(imp)
            if theirs and theirs != mine and theirs not in ALLOWED[mine]:
                bad.append(f"{mod} ({mine}) imports {imp} ({theirs})")
    return bad


def load_tree() -> dict[str, tuple[str, bool]]:
    return {module_name(p): (p.read_text(encoding="utf-8"), p.name == "__init__.py")
            for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}


# Back-arrows still being removed, each named with the work that removes it. An entry that no
# longer occurs fails the test, so this list can only shrink.
PENDING: set[tuple[str, str]] = set()


def pending(v: str) -> tuple[str, str] | None:
    return next((p for p in PENDING if v.startswith(p[0] + " ") and f"imports {p[1]}" in v), None)


def test_every_import_points_down_the_layers():
    found = violations(load_tree())
    assert [v for v in found if not pending(v)] == []
    assert {pending(v) for v in found} - {None} == PENDING, "a PENDING back-arrow is gone: drop it from the list"


def test_a_back_arrow_is_caught():
    """The check is not vacuous: a synthetic calibration module importing the daemon fails it."""
    tree = load_tree()
    tree["calibration.synthetic"] = ("import numpy\nfrom daemon.bus.storage import atomic_write_text\n", False)
    tree["drivers.synthetic"] = ("def f():\n    from fakes import world\n", False)
    tree["daemon.bus.synthetic"] = ("from ..ritad import main\n", False)
    found = violations(tree)
    assert any(v.startswith("calibration.synthetic ") for v in found)
    assert any(v.startswith("drivers.synthetic ") for v in found)
    assert any(v.startswith("daemon.bus.synthetic ") and "daemon.ritad" in v for v in found)


def import_graph(tree: dict[str, tuple[str, bool]]) -> dict[str, set[str]]:
    """module -> project modules it imports (``if TYPE_CHECKING:`` imports count too: a type-only
    cycle is still two modules that cannot be understood apart)."""
    return {mod: {i for i in project_imports(source, mod, is_pkg) if i in tree and i != mod}
            for mod, (source, is_pkg) in tree.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state and (c := visit(m)):
                return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state and (c := visit(n)):
            return c
    return None


PENDING_CYCLE_EDGES: set[tuple[str, str]] = set()  # (importer, imported) edges still being removed


def test_no_import_cycles():
    graph = import_graph(load_tree())
    for a, b in PENDING_CYCLE_EDGES:
        assert b in graph[a], f"{a} -> {b} is gone: drop it from PENDING_CYCLE_EDGES"
        graph[a].discard(b)
    assert find_cycle(graph) is None


def test_a_cycle_is_caught():
    tree = {"fakes.a": ("from fakes import b\n", False), "fakes.b": ("def f():\n    import fakes.a\n", False)}
    assert find_cycle(import_graph(tree)) == ["fakes.a", "fakes.b", "fakes.a"]


def test_no_product_module_imports_the_simulator():
    """daemon/, drivers/ and calibration/ never name fakes: the simulator enters by configuration only."""
    tree = load_tree()
    bad = [f"{mod} imports {imp}" for mod, (src, is_pkg) in sorted(tree.items())
           if mod.split(".")[0] in ("daemon", "drivers", "calibration")
           for imp in sorted(project_imports(src, mod, is_pkg)) if imp.split(".")[0] == "fakes"]
    assert bad == []


def test_no_product_module_names_a_simulator_command_or_holds_its_world():
    """The sim.* commands live in the simulator's plugin (fakes/plugin.py): the product names none."""
    from fakes.plugin import COMMANDS

    names = [c.name for c in COMMANDS]
    hits = []
    for top in ("daemon", "drivers", "calibration"):
        for path in sorted((ROOT / top).rglob("*")):
            if path.suffix not in (".py", ".js", ".html") or "__pycache__" in path.parts:
                continue
            text = path.read_text(encoding="utf-8")
            hits += [f"{path.relative_to(ROOT)}: {n}" for n in names if n in text]
            if re.search(r"\bworld\b\s*[:=]", text) or "start_sim_world" in text:
                hits.append(f"{path.relative_to(ROOT)}: holds a world")
    assert hits == []
