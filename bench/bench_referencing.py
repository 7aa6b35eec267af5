"""Benchmark of referencing compute: `ritactl --json recompute` of a full-size referencing folder.

One referencing dataset with a rendered 4024×3036 image (simulated world, bench/common.py)
is written once and cached in the temp directory (``--rebuild`` writes it again), with the
result.json of the code that built it, so a recompute also reports how far the current code
lands from that stored result. Then, alternately and each in a fresh process:

* the **import baseline**: an interpreter that imports every module a recompute ends up
  importing (recorded from one full run) and exits;
* the **full run**: ``ritactl --json recompute FOLDER`` (validation, image decode, detection,
  PnP, SCS, plate and robot pose, Monte Carlo uncertainty, camera-model checks, verdict).

The goal is the full run's wall time, what the operator waits for (imports and validation included):
median ≤ ``GOAL_S``. Compute = median(full) − median(baseline); ratio = median(full) / median(baseline); peak
memory is the full run's peak RSS (its own VmHWM); CPU time (user + system, ``os.wait4``) is
printed too: it says what the computation costs whatever the load. A missed goal prints **MISSED**, the
exit code stays 0. ``--profile`` also profiles one recompute in this process (cProfile,
the first call after the imports, as in a fresh process) and prints the top 15.

Run: ``.venv/bin/python bench/bench_referencing.py [--repeats N] [--profile] [--rebuild]``
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import FULL, ROOT, machine, write_referencing_folder  # noqa: E402

GOAL_S = 1.0  # ritactl recompute of a 12 MP referencing, end to end
GOAL_MIB = 150.0
CACHE = Path(tempfile.gettempdir()) / f"rita-bench-referencing-{FULL[0]}x{FULL[1]}" / "ref"

#: the full run, as the ritactl entry point does it, writing its peak RSS (VmHWM, kB) at exit: the
#: rusage of a child counts its spawner's memory too (Linux keeps the old high-water mark across exec)
FULL_RUN = ("import atexit, sys\n"
            "atexit.register(lambda: open(sys.argv.pop(1), 'w').write(\n"
            "    [ln.split()[1] for ln in open('/proc/self/status') if ln.startswith('VmHWM')][0]))\n"
            "from daemon.ctl.main import main\nsys.exit(main(sys.argv[2:]))\n")
#: the full run, recording the modules it imported, in import order (sys.modules keeps it)
RECORD = ("import atexit, json, sys\n"
          "atexit.register(lambda: open(sys.argv.pop(1), 'w').write(json.dumps(list(sys.modules))))\n"
          "from daemon.ctl.main import main\nsys.exit(main(sys.argv[2:]))\n")
#: the baseline: import those modules in the same order (one that cannot be imported alone is skipped),
#: numpy and OpenCV with one thread each as ritactl recompute loads them
BASELINE = ("import importlib, json, os, sys\nos.environ.setdefault('OPENBLAS_NUM_THREADS', '1')\n"
            "os.environ.setdefault('OPENCV_FOR_THREADS_NUM', '1')\n"
            "for m in json.loads(open(sys.argv[1]).read()):\n"
            "    try:\n        importlib.import_module(m)\n    except Exception:\n        pass\n")


def dataset(rebuild: bool) -> Path:
    """The cached referencing folder, written (with its result.json) when missing."""
    if rebuild and CACHE.parent.exists():
        shutil.rmtree(CACHE.parent)
    if (CACHE / "result.json").exists():
        return CACHE
    shutil.rmtree(CACHE.parent, ignore_errors=True)
    tmp = CACHE.parent.with_name(CACHE.parent.name + f".{os.getpid()}")
    write_referencing_folder(tmp / "ref")
    from daemon.compute.files import write_result_files
    from daemon.compute.recompute import recompute

    write_result_files(tmp / "ref", recompute(tmp / "ref")[0])
    tmp.rename(CACHE.parent)
    return CACHE


def run(args: list[str]) -> tuple[float, float]:
    """(wall s, CPU s: user + system) of one fresh interpreter running ``args``; stops the bench on
    a failure."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, *args], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE)
    err = p.stderr.read() if p.stderr else b""
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.stderr:
        p.stderr.close()
    if p.returncode not in (0, 1):  # 1 = a "warn" verdict: still a full computation
        raise SystemExit(f"python {' '.join(args[1:4])} ... exited {p.returncode}: "
                         f"{err.decode(errors='replace')[-2000:]}")
    return wall, usage.ru_utime + usage.ru_stime


def run_full(folder: Path, hwm: Path) -> tuple[float, float, float]:
    """(wall s, CPU s, peak RSS MiB) of one ``ritactl --json recompute FOLDER``."""
    wall, cpu = run(["-c", FULL_RUN, str(hwm), "--json", "recompute", str(folder)])
    return wall, cpu, int(hwm.read_text()) / 1024


def modules(folder: Path) -> Path:
    """The modules a full recompute imports (recorded once), as a JSON file for the baseline."""
    out = Path(tempfile.mkdtemp(prefix="rita-bench-mods-")) / "modules.json"
    run(["-c", RECORD, str(out), "--json", "recompute", str(folder)])
    return out


#: one recompute profiled in a fresh process, after the imports a ritactl run has done, threads as
#: ritactl sets them
PROFILE = ("import cProfile, os, pstats, sys, time\nfrom pathlib import Path\n"
           "os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')\n"
           "os.environ.setdefault('OPENCV_FOR_THREADS_NUM', '1')\n"
           "import daemon.ctl.main\n"
           "from daemon.compute.recompute import recompute\n"
           "prof = cProfile.Profile()\nt0 = time.perf_counter()\nprof.enable()\n"
           "recompute(Path(sys.argv[1]))\n"
           "prof.disable()\n"
           "print(f'recompute under cProfile, fresh process: {time.perf_counter() - t0:.3f} s')\n"
           "pstats.Stats(prof).sort_stats('tottime').print_stats(15)\n")


def profile(folder: Path) -> str:
    """The top 15 functions by own time of one recompute (cProfile) in a fresh process."""
    out = subprocess.run([sys.executable, "-c", PROFILE, str(folder)], cwd=ROOT, capture_output=True,
                         text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, check=True).stdout
    head, _, table = out.partition("   ncalls")
    return head.splitlines()[0] + "\n\n   ncalls" + table.rstrip()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7, help="runs of each process (>= 5)")
    ap.add_argument("--profile", action="store_true", help="also profile one recompute in this process")
    ap.add_argument("--rebuild", action="store_true", help="write the cached dataset again")
    a = ap.parse_args()
    folder = dataset(a.rebuild)
    mods = modules(folder)
    load0 = os.getloadavg()
    base, full, rss, cpu_base, cpu_full = [], [], [], [], []
    for _ in range(max(a.repeats, 5)):  # alternated: a load change hits both alike
        wall, cpu = run(["-c", BASELINE, str(mods)])
        base.append(wall)
        cpu_base.append(cpu)
        wall, cpu, peak = run_full(folder, mods.with_name("hwm"))
        full.append(wall)
        cpu_full.append(cpu)
        rss.append(peak)
    load1 = os.getloadavg()
    med = statistics.median
    compute = med(full) - med(base)
    from daemon.compute.recompute import recompute

    _, diff = recompute(folder)
    png_mib = (folder / "run0.png").stat().st_size / 2 ** 20
    n_mods = len(json.loads(mods.read_text()))
    shutil.rmtree(mods.parent, ignore_errors=True)

    def verdict(ok: bool) -> str:
        return "met" if ok else "**MISSED**"
    print(machine())
    print(f"load average {load0[0]:.2f} before, {load1[0]:.2f} after; n = {len(full)} of each, alternated")
    print(f"\nreferencing folder {folder}: one {FULL[0]}×{FULL[1]} 8-bit PNG ({png_mib:.1f} MiB)\n")
    print("| metric | median (min–max) | goal | |\n|---|---|---|---|")
    print(f"| import baseline ({n_mods} modules, interpreter included) | {med(base):.3f} s "
          f"({min(base):.3f}–{max(base):.3f}) | | |")
    print(f"| `ritactl --json recompute` | {med(full):.3f} s ({min(full):.3f}–{max(full):.3f}) "
          f"| ≤ {GOAL_S} s | {verdict(med(full) <= GOAL_S)} |")
    print(f"| compute = full − baseline | {compute:.3f} s | | |")
    print(f"| ratio full / baseline | {med(full) / med(base):.2f} | | |")
    print(f"| CPU (user + system): baseline / full / compute | {med(cpu_base):.3f} / {med(cpu_full):.3f} / "
          f"{med(cpu_full) - med(cpu_base):.3f} s | | |")
    print(f"| peak RSS of the full run | {med(rss):.0f} MiB (max {max(rss):.0f}) | ≤ {GOAL_MIB:g} MiB | "
          f"{verdict(max(rss) <= GOAL_MIB)} |")
    print(f"| largest difference to the stored result.json | "
          f"{'none stored' if diff is None else f'{float(diff):.3g}'} | | |")
    if a.profile:
        print("\n" + profile(folder))
    return 0


if __name__ == "__main__":
    sys.exit(main())
