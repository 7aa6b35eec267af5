"""Each install extra works from a clean venv (issue 35): the base install, ``[laptop]`` and ``[console]``.

Real installs, as an operator's laptop makes them: ``pip install 'rita[EXTRA]'`` of a wheel built
from this checkout, requirements resolved by pip from the package index (CI: .ci/run on a fresh
machine with registry access; pip's own cache keeps repeats cheap). The venvs are cached across
runs under ``$RITA_VENV_CACHE`` (default ~/.cache/rita-venvs), keyed by pyproject.toml's content
and the Python version: a changed requirement builds them again (the three side by side, without
pip in them: the test venv's ``pip --python`` installs into each, ``--no-compile``). Each session
installs only this checkout's wheel beside them (``--no-deps --target``: the requirements did not
change with the key), so the code tested is the code here. Nothing of the test venv is visible to them.

Each offline verb then runs with the venv's own ``ritactl`` against a ``ritad`` on the simulated
world (in this process, ipc in a temp dir): ``validate``; ``recompute`` of one dataset per
procedure the independent writer makes (tests/dataset_writer.py: referencing, experiment,
measure-mark, intrinsics); ``plate survey`` of photographs fetched from the sim; ``console`` start;
``record`` and ``replay``. Where the extra does not cover a verb it exits 5 naming the extra, and writes
nothing.
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import time
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest

from daemon.ctl import extras as ctl_extras

from tests.dataset_writer import K, write_experiment, write_intrinsics, write_referencing
from tests.ritad_up import ritad_in_process

ROOT = Path(__file__).resolve().parents[2]
EXTRAS = ("base", "laptop", "console")
#: what a wheel is built from: the packages pyproject.toml names, and the files it reads
SOURCES = ("pyproject.toml", "README.md", "daemon", "drivers", "calibration", "fakes")
#: what a cached venv holds (2: the requirements only, rita uninstalled); a new layout is a new key
CACHE_LAYOUT = b"2"
pytestmark = pytest.mark.slow  # builds venvs on the first run (pip installs), then reuses them


def _env(site: Path | None = None) -> dict[str, str]:
    """The environment of a clean venv's programs: nothing of the test venv or this checkout (``site``:
    this session's install of the checkout, on the path)."""
    drop = ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME", "PIP_REQUIRE_VIRTUALENV", "PYTHONSTARTUP")
    env = {**{k: v for k, v in os.environ.items() if k not in drop}, "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    return {**env, "PYTHONPATH": str(site)} if site else env


def _run(*argv: object, cwd: Path, timeout: float = 600,
         site: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(a) for a in argv], capture_output=True, text=True, timeout=timeout, cwd=cwd,
                          env=_env(site))


@dataclass(frozen=True)
class Install:
    """One extra: the cached venv with its requirements, and this session's install of the checkout.

    The checkout goes into a folder of this session (``pip install --no-deps --target``), not into the
    shared venv: two suites on one machine (two checkouts, one pyproject.toml) never run each other's code.
    """

    venv: Path
    site: Path

    def run(self, *argv: object, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
        """``ritactl ARGV`` as this install has it (the console script pip wrote for the venv's Python)."""
        return _run(self.site / "bin" / "ritactl", *argv, cwd=cwd, timeout=timeout, site=self.site)


def _cache_root() -> Path:
    made = (ROOT / "pyproject.toml").read_bytes() + sys.version.encode() + CACHE_LAYOUT
    key = hashlib.sha256(made).hexdigest()[:16]
    return Path(os.environ.get("RITA_VENV_CACHE") or Path.home() / ".cache" / "rita-venvs") / key


#: a cache of venvs for another pyproject.toml that no run used for this long is removed
STALE_S = 14 * 24 * 3600


def _prune(root: Path) -> None:
    """Remove the cached venvs of other keys unused for STALE_S (each is ~0.5 GB), never one in use."""
    for lock_file in root.parent.glob("*.lock"):
        venvs = lock_file.with_suffix("")
        if venvs == root or time.time() - lock_file.stat().st_mtime < STALE_S:
            continue
        with open(lock_file, "a") as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)  # a suite using it holds the lock
            except BlockingIOError:
                continue
            shutil.rmtree(venvs, ignore_errors=True)
            lock_file.unlink()


def _wheel(tmp: Path) -> Path:
    """A wheel of this checkout, built from a copy (the build leaves build/ and egg-info behind)."""
    src = tmp / "src"
    src.mkdir()
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(ROOT / name, src / name)
    res = _run(sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", tmp / "dist", src, cwd=tmp)
    assert res.returncode == 0, f"building the wheel failed:\n{res.stdout[-3000:]}{res.stderr[-3000:]}"
    (wheel,) = (tmp / "dist").glob("rita-*.whl")
    return wheel


def _pip(venv: Path, *argv: object, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """This test venv's pip acting on ``venv`` (``pip --python``): the clean venvs need no pip of their own
    (``venv --without-pip`` skips ensurepip's install, seconds per venv), and pip still resolves for the
    venv's interpreter, as the operator's own pip would."""
    python = venv / "bin" / "python"
    return _run(sys.executable, "-m", "pip", "--python", python, *argv, cwd=cwd, timeout=timeout)


def _install(venv: Path, wheel: Path, extra: str, cwd: Path) -> None:
    """A fresh venv with ``rita[extra]``'s requirements: a real pip install, checked, then rita itself
    removed (each session installs its own checkout beside the venv). ``--no-compile``: Python compiles
    what a verb imports on its first run, not every module of numpy, OpenCV and matplotlib at install."""
    shutil.rmtree(venv, ignore_errors=True)
    res = _run(sys.executable, "-m", "venv", "--without-pip", venv, cwd=cwd)
    assert res.returncode == 0, res.stderr
    spec = f"rita{'' if extra == 'base' else f'[{extra}]'} @ {wheel.as_uri()}"
    res = _pip(venv, "install", "-q", "--no-compile", spec, cwd=cwd, timeout=1200)
    assert res.returncode == 0, f"pip install {spec} failed:\n{res.stdout[-3000:]}{res.stderr[-3000:]}"
    res = _pip(venv, "check", cwd=cwd)  # without --no-deps: nothing broken
    assert res.returncode == 0, f"{extra}: {res.stdout}{res.stderr}"
    res = _pip(venv, "uninstall", "-q", "-y", "rita", cwd=cwd)
    assert res.returncode == 0, res.stderr
    (venv / ".ready").write_text(spec + "\n")


def _session_install(venv: Path, wheel: Path, site: Path, cwd: Path) -> Install:
    """This checkout's wheel into a folder of this session (the requirements did not change with the key)."""
    res = _pip(venv, "install", "-q", "--no-deps", "--no-compile", "--target", site, wheel, cwd=cwd)
    assert res.returncode == 0, res.stderr[-3000:]
    return Install(venv, site)


@pytest.fixture(scope="session")
def venvs(tmp_path_factory) -> dict[str, Install]:
    """{extra: its install}: the venvs built once per pyproject.toml, this checkout installed per session.
    The three venvs are independent: built side by side (pip waits on the index and the disk as much as
    on the CPU), each still from nothing."""
    tmp = tmp_path_factory.mktemp("wheel")
    wheel = _wheel(tmp)
    root = _cache_root()
    root.mkdir(parents=True, exist_ok=True)
    with open(root.with_suffix(".lock"), "w") as lock:  # another pytest run on this machine waits here
        fcntl.flock(lock, fcntl.LOCK_EX)
        _prune(root)  # the lock file's time is this key's last use: "w" just set it
        missing = [e for e in EXTRAS if not (root / e / ".ready").exists()]  # first run, or a build cut short
        with ThreadPoolExecutor(len(EXTRAS)) as pool:
            for done in [pool.submit(_install, root / e, wheel, e, tmp) for e in missing]:
                done.result()  # re-raises a build's failure, naming pip's error
    with ThreadPoolExecutor(len(EXTRAS)) as pool:
        jobs = {e: pool.submit(_session_install, root / e, wheel, tmp / e, tmp) for e in EXTRAS}
        return {e: job.result() for e, job in jobs.items()}


@pytest.fixture(scope="session")
def sim(tmp_path_factory) -> Iterator[tuple[str, Path]]:
    """(endpoint, data dir) of a ritad on the simulated world, with a few survey photographs made."""
    rt = tmp_path_factory.mktemp("rt")
    with ritad_in_process(rt, tracker="sim:?time_scale=0.002") as (d, c):
        c.call("sim.survey_images", views=4, width_px=1200, timeout=300)
        yield d.server.endpoints[0], rt / "data"


@pytest.fixture(scope="session")
def datasets(tmp_path_factory) -> dict[str, Path]:
    """One dataset folder per procedure the independent writer makes."""
    from daemon.compute.recompute import recompute

    tmp = tmp_path_factory.mktemp("datasets")
    rob_H_cam = write_referencing(tmp / "referencing")
    calibration = recompute(tmp / "referencing")[0]
    write_experiment(tmp / "experiment", calibration, rob_H_cam, np.array([1500.0, 200.0, 3.0]))
    mm = tmp / "measure-mark"  # one stop of the experiment, as docs/datasets.md's measure-mark obs
    shutil.copytree(tmp / "experiment", mm)
    state = json.loads((mm / "state.json").read_text())
    stop = {k: v for k, v in state["obs"].pop("stops")[0].items() if k not in ("k", "rep")}
    state["procedure"], state["obs"]["stop"] = "measure-mark", stop
    (mm / "state.json").write_text(json.dumps(state))
    for png in mm.glob("*.png"):
        if png.name != stop["image"]:
            png.unlink()
    write_intrinsics(tmp / "intrinsics")
    return {name: tmp / name for name in ("referencing", "experiment", "measure-mark", "intrinsics")}


def ritactl(inst: Install, *argv: object, cwd: Path,
            timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return inst.run(*argv, cwd=cwd, timeout=timeout)


def _missing(res: subprocess.CompletedProcess[str], extra: str) -> None:
    assert res.returncode == 5, res.stdout[-2000:] + res.stderr[-2000:]
    assert f"pip install 'rita[{extra}]'" in res.stderr and "Traceback" not in res.stderr, res.stderr


def test_the_packages_ritactl_checks_are_the_extras_in_pyproject():
    """daemon/ctl/extras.py (what a verb imports before it starts) names what pyproject.toml installs."""
    import tomllib

    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    for extra in ctl_extras.EXTRAS.values():
        listed = {re.split(r"[<>=!~;\[ ]", r, maxsplit=1)[0].lower() for r in extras[extra.name]}
        assert set(extra.modules.values()) == listed, (extra.name, listed)


def test_the_venvs_hold_this_checkout_and_only_their_extras(venvs, tmp_path):
    probe = "import daemon, importlib.util as u; print(daemon.__file__); print(*(m for m in " \
            "('numpy', 'cv2', 'matplotlib', 'aiohttp', 'harvesters', 'serial') if u.find_spec(m)))"
    has = {"base": "", "laptop": "numpy cv2 matplotlib", "console": "aiohttp"}
    for extra, inst in venvs.items():
        res = _run(inst.venv / "bin" / "python", "-c", probe, cwd=tmp_path, site=inst.site)
        where, found = res.stdout.splitlines()
        assert where.startswith(str(inst.site)), where  # the installed copy, not this checkout
        assert found.split() == has[extra].split(), (extra, found)


@pytest.mark.parametrize("extra", EXTRAS)
def test_validate_works_in_every_install(venvs, datasets, tmp_path, extra):
    res = ritactl(venvs[extra], "validate", *datasets.values(), cwd=tmp_path)
    assert res.returncode == 0 and res.stdout.count(": valid") == len(datasets), res.stdout + res.stderr


@pytest.mark.parametrize("extra", ["base", "console"])
def test_offline_computing_without_the_laptop_extra_exits_5_before_writing(venvs, datasets, sim, tmp_path,
                                                                            extra):
    out = tmp_path / "out"
    _missing(ritactl(venvs[extra], "recompute", datasets["experiment"], "--out", out, cwd=tmp_path), "laptop")
    design = sim[1] / "sim" / "plate.json"
    _missing(ritactl(venvs[extra], "plate", "survey", sim[1] / "sim" / "survey", "--plate", design,
                     "--out", out, cwd=tmp_path), "laptop")
    assert not out.exists()


@pytest.mark.parametrize("procedure", ["referencing", "experiment", "measure-mark", "intrinsics"])
def test_laptop_recomputes_each_procedure(venvs, datasets, tmp_path, procedure):
    """Failed before issue 35 for the experiment: matplotlib missing, exit 2, a partial report left."""
    out = tmp_path / "out"
    res = ritactl(venvs["laptop"], "recompute", datasets[procedure], "--out", out, cwd=tmp_path)
    assert res.returncode in (0, 1) and "Traceback" not in res.stderr, res.stdout[-2000:] + res.stderr[-2000:]
    result = json.loads((out / "result.json").read_text())
    assert result["procedure"] == procedure
    for name in result.get("files", []):  # the experiment's report.md/.csv and clusters.png
        assert (out / name).stat().st_size > 0, name
    if procedure == "experiment":
        assert (out / "clusters.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    if procedure == "intrinsics":  # the writer's own pinhole camera, found again
        assert np.allclose(result["camera_model"]["K"], K, atol=0.5), result["camera_model"]["K"]


def test_laptop_fetches_and_surveys_the_plate(venvs, sim, tmp_path):
    endpoint, _ = sim
    res = ritactl(venvs["laptop"], "--endpoint", endpoint, "fetch", "sim", "--to", tmp_path / "got",
                  cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    got = tmp_path / "got" / "sim"
    res = ritactl(venvs["laptop"], "plate", "survey", got / "survey", "--plate", got / "plate.json",
                  "--out", tmp_path / "plate.json", cwd=tmp_path, timeout=600)
    assert res.returncode in (0, 1), res.stdout[-2000:] + res.stderr[-2000:]
    assert json.loads((tmp_path / "plate.json").read_text())["survey"]["verdict"] in ("ok", "warn")


def test_console_needs_its_extra_and_starts_with_it(venvs, sim, tmp_path):
    endpoint, _ = sim
    for extra in ("base", "laptop"):
        _missing(ritactl(venvs[extra], "--endpoint", endpoint, "console", "--port", "0", "--duration", "1",
                         cwd=tmp_path), "console")
    inst = venvs["console"]
    argv = [inst.site / "bin" / "ritactl", "--endpoint", endpoint, "console", "--port", "0",
            "--duration", "30"]
    with subprocess.Popen([str(a) for a in argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                          cwd=tmp_path, env=_env(inst.site)) as p:
        try:
            url = _console_url(p)
            with urllib.request.urlopen(url, timeout=30) as page:  # noqa: S310 - 127.0.0.1, the printed URL
                assert page.status == 200 and "<html" in page.read().decode().lower()
        finally:
            p.terminate()
            p.wait(timeout=30)


def _console_url(p: subprocess.Popen[str]) -> str:
    """The tokened http://127.0.0.1:PORT/… URL the console prints, read line by line (30 s at most)."""
    deadline, seen = time.monotonic() + 30, []
    assert p.stdout is not None
    while time.monotonic() < deadline:
        line = p.stdout.readline()
        if not line:
            break
        seen.append(line)
        m = re.search(r"http://127\.0\.0\.1:\d+/\S*", line)
        if m:
            return m.group(0)
    raise AssertionError(f"no URL printed: {''.join(seen)} {p.stderr.read() if p.poll() is not None else ''}")


@pytest.mark.parametrize("extra", EXTRAS)
def test_record_and_replay_work_in_every_install(venvs, sim, tmp_path, extra):
    endpoint, _ = sim
    inst, mcap = venvs[extra], tmp_path / "s.mcap"
    res = ritactl(inst, "--endpoint", endpoint, "record", "--out", mcap, "--duration", "2", cwd=tmp_path)
    assert res.returncode == 0 and mcap.stat().st_size > 0, res.stdout[-2000:] + res.stderr[-2000:]
    res = ritactl(inst, "replay", mcap, "--speed", "max", "--no-wait", "--linger", "0",
                  "--endpoint", f"ipc://{tmp_path}/replay", cwd=tmp_path)
    assert res.returncode == 0 and re.search(r"replayed [1-9]\d* messages", res.stderr), res.stderr[-2000:]

