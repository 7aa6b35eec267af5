"""The laptop install: the base package is the thin client, and pip finds nothing broken.

A wheel is assembled from this tree with the requirements exactly as setuptools reads
them from pyproject.toml (offline, no `wheel` package here: a plain zip with METADATA,
entry points and the packages), and installed into a fresh venv that sees only pyzmq,
msgpack and jsonschema (with its requirements) (linked in from the test venv through a .pth file, standing in for what pip
would download). `pip install` then needs no --no-deps, `pip check` reports no broken
requirement, `ritactl --help` works, and `ritad` names the extra to install instead of
showing a traceback.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[2]
#: the base (client) requirements: the bus, `ritactl validate`'s schemas, `ritactl record`'s MCAP and its JSON encoder
CLIENT = ("pyzmq", "msgpack", "jsonschema", "mcap")
HEAVY = {"numpy", "opencv-python-headless", "harvesters", "genicam", "pyserial", "matplotlib"}


def names(requirements: list[str]) -> set[str]:
    return {re.split(r"[<>=!~;\[ ]", r, maxsplit=1)[0].lower() for r in requirements}


def test_base_requirements_are_the_client_and_the_robot_extra_has_the_rest():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert names(project["dependencies"]) == set(CLIENT)
    extras = project["optional-dependencies"]
    assert HEAVY <= names(extras["robot"])
    # no device packages on a laptop; matplotlib draws the experiment's plot that `recompute --out` writes
    assert names(extras["laptop"]) == {"numpy", "opencv-python-headless", "matplotlib"}


def _closure(dist_names: list[str]) -> list[str]:
    """The distributions plus everything they require (no extras), as installed here."""
    seen: list[str] = []
    todo = list(dist_names)
    while todo:
        name = todo.pop()
        if name.lower() in (s.lower() for s in seen):
            continue
        seen.append(name)
        for text in metadata.distribution(name).requires or []:
            req = Requirement(text)
            if req.marker is None or req.marker.evaluate({"extra": ""}):
                todo.append(req.name)
    return seen


def _link_site(dist_names: list[str], into: Path) -> None:
    """Symlink the given installed distributions (code + dist-info) into ``into``."""
    into.mkdir()
    for name in dist_names:
        dist = metadata.distribution(name)
        site = Path(dist.locate_file(""))
        tops = {Path(f.parts[0]) for f in dist.files or [] if f.parts and not f.parts[0].endswith(".dist-info")}
        tops.add(Path(dist._path.name))  # the dist-info directory itself
        for top in tops:
            if (site / top).exists() and not (into / top).exists():
                (into / top).symlink_to(site / top)


WHEEL_BUILDER = r"""
import pathlib, sys, zipfile
from setuptools.config.pyprojecttoml import apply_configuration
from setuptools.dist import Distribution

root, out = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
d = Distribution()
apply_configuration(d, str(root / "pyproject.toml"))
m = d.metadata
lines = ["Metadata-Version: 2.1", f"Name: {m.name}", f"Version: {m.version}",
         f"Requires-Python: {d.python_requires}"]
lines += [f"Requires-Dist: {r}" for r in d.install_requires]
for extra, reqs in d.extras_require.items():
    lines.append(f"Provides-Extra: {extra}")
    lines += [f'Requires-Dist: {r}; extra == "{extra}"' for r in reqs]
info = f"{m.name}-{m.version}.dist-info"
scripts = "\n".join(d.entry_points["console_scripts"])
wheel = out / f"{m.name}-{m.version}-py3-none-any.whl"
with zipfile.ZipFile(wheel, "w") as z:
    for pkg in ("daemon", "drivers", "calibration", "fakes"):
        for f in (root / pkg).rglob("*"):
            if f.suffix in (".py", ".toml", ".json") and "__pycache__" not in f.parts:
                z.write(f, f.relative_to(root).as_posix())
    z.writestr(f"{info}/METADATA", "\n".join(lines) + "\n")
    z.writestr(f"{info}/WHEEL", "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n")
    z.writestr(f"{info}/entry_points.txt", f"[console_scripts]\n{scripts}\n")
    z.writestr(f"{info}/RECORD", "")
print(wheel)
"""


@pytest.mark.slow
def test_laptop_install_without_no_deps_has_no_broken_requirements(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PIP_REQUIRE_VIRTUALENV")}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    run = lambda *a, **kw: subprocess.run([str(x) for x in a], capture_output=True, text=True, timeout=300,  # noqa
                                          env=env, cwd=tmp_path, **kw)
    res = run(sys.executable, "-W", "ignore", "-c", WHEEL_BUILDER, ROOT, tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    wheel = Path(res.stdout.strip())
    venv = tmp_path / "laptop"
    res = run(sys.executable, "-m", "venv", venv)
    assert res.returncode == 0, res.stderr
    py = venv / "bin" / "python"
    site = Path(run(py, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))").stdout.strip())
    _link_site(_closure(list(CLIENT)), tmp_path / "bus")
    (site / "bus.pth").write_text(str(tmp_path / "bus") + "\n")
    res = run(py, "-m", "pip", "install", "--no-index", wheel)  # no --no-deps: requirements must resolve
    assert res.returncode == 0 and "ERROR" not in res.stdout + res.stderr, res.stdout[-2000:] + res.stderr[-2000:]
    res = run(py, "-m", "pip", "check")
    assert res.returncode == 0 and "No broken requirements" in res.stdout, res.stdout + res.stderr
    res = run(venv / "bin" / "ritactl", "--help")
    assert res.returncode == 0 and "usage" in res.stdout.lower(), res.stderr[-2000:]
    res = run(venv / "bin" / "ritad", "--sim")
    assert res.returncode == 1 and "pip install 'rita[robot]'" in res.stderr and "Traceback" not in res.stderr
