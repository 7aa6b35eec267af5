"""README's "Using it" block, executed as written against ``ritad --sim``.

The fenced block under "## Using it" is parsed from README.md; only the ``.venv/bin/``
prefix (this interpreter's bin folder) and the runtime dir (a temp dir) are
substituted. The ``ritad`` line is started in the background, as the README says
(leave it running), and the test waits until every device is READY, as an operator
would glance at ``status``. Every other line runs in bash in a temp working folder
with the ``export`` lines before it; each must exit 0.
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from daemon.bus.client import Client

ROOT = Path(__file__).resolve().parents[2]
README_RUNTIME = "/tmp/rita"


def using_it_block(text: str) -> list[str]:
    """The command lines of the first fenced block after "## Using it" (continuations joined)."""
    m = re.search(r"^## Using it\n(?:.*\n)*?```sh\n((?:.*\n)*?)```", text, re.MULTILINE)
    assert m, "README.md has no ```sh block under '## Using it'"
    lines, cont = [], ""
    for raw in m.group(1).splitlines():
        if raw.rstrip().endswith("\\"):
            cont += raw.rstrip()[:-1] + " "
            continue
        line = (cont + raw).strip()
        cont = ""
        if line and not line.startswith("#"):
            lines.append(line)
    return lines


README_SCRATCH = "/tmp/rita-walk"


def localise(line: str, runtime: Path, scratch: Path | None = None) -> str:
    """This interpreter's bin folder for the checkout's .venv/bin; temp dirs for /tmp/rita and the scratch."""
    bin_dir = Path(sys.executable).parent
    line = line.replace("$PWD/.venv/bin", str(bin_dir)).replace(".venv/bin/", f"{bin_dir}/")
    line = line.replace(README_SCRATCH, str(scratch or runtime / "walk"))  # before /tmp/rita, its prefix
    return line.replace(README_RUNTIME, str(runtime))


def carries_over(line: str) -> bool:
    """A line whose effect the next lines need: an export, or the change into the scratch folder."""
    return line.startswith("export ") or " cd " in f" {line}"


def test_readme_block_parses() -> None:
    lines = using_it_block((ROOT / "README.md").read_text())
    assert lines[0].startswith(".venv/bin/ritad --sim") and any("calibrate" in ln for ln in lines)
    starts = (".venv/bin/", "export ", "mkdir ", "ritactl ", "python ")
    assert all(ln.startswith(starts) for ln in lines), lines
    # the walk starts in a scratch folder
    assert any(carries_over(ln) and README_SCRATCH in ln for ln in lines[:3])


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_readme_using_it_runs_verbatim(tmp_path: Path) -> None:
    """From a stand-in for the checkout (the README's $PWD), which stays empty: all lands in the scratch."""
    runtime, work, checkout = tmp_path / "rt", tmp_path / "work", tmp_path / "checkout"
    runtime.mkdir()
    checkout.mkdir()
    lines = [localise(ln, runtime, work) for ln in using_it_block((ROOT / "README.md").read_text())]
    daemon_line, rest = lines[0], lines[1:]
    log = open(tmp_path / "ritad.log", "wb")
    env = {k: v for k, v in os.environ.items() if k not in ("RITA_ENDPOINT", "RITA_RUNTIME_DIR")}
    proc = subprocess.Popen(["bash", "-c", f"exec {daemon_line}"], cwd=checkout, stdout=log,
                            stderr=subprocess.STDOUT, env=env)
    try:
        with Client(f"ipc://{runtime}/cmd", timeout=2) as c:
            c.wait_ready(timeout=120, alive=lambda: proc.poll() is None)
        exports: list[str] = []
        for line in rest:
            if carries_over(line):
                exports.append(line)
            script = "\n".join([*exports, *([] if carries_over(line) else [line])])
            r = subprocess.run(["bash", "-c", script], cwd=checkout, capture_output=True, text=True,
                               timeout=600, env=env)
            assert r.returncode == 0, f"{line}\n exited {r.returncode}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
            assert "Traceback" not in r.stderr, r.stderr
        for written in ("sim/plate.json", "s.mcap", "plate.json"):
            assert (work / written).exists(), written
        assert list((work / "rita-data" / "procedures").glob("*-experiment-*/clusters.png"))
        assert not list(checkout.iterdir()), list(checkout.iterdir())  # the checkout is left as it was
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        log.close()
