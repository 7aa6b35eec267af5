import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

#: the files whose run on one worker is longest, longest first (`make test` runs whole files per
#: worker): scheduled before the rest so that no worker picks up a long file near the end
#: (longest-first scheduling). Order only: the suite's content does not depend on it, and
#: tests/system/test_structure.py checks each path still exists. `--no-loadscope-reorder` (Makefile)
#: keeps it. Ranked by the per-file sums of junit times (docs/benchmarks.md, "Test suite"): the files of
#: 35 s or more in both full runs of 2026-11-28 09:55 and 10:20 UTC (before and after the renderer's
#: speed-up), in the order of the second; the clean venvs' file placed by its cold-cache time.
LONGEST_FIRST = (
    "tests/system/test_worker_e2e.py",
    "tests/system/test_readme.py",
    "tests/console/test_console_browser.py",
    "tests/console/test_console_stop_acceptance.py",
    "tests/calibration/test_calibration_sim.py",
    "tests/system/test_stop_latch.py",
    "tests/system/test_extras.py",  # pip installs three clean venvs on a machine without its cache
    "tests/system/test_commission.py",
    "tests/system/test_plate_survey.py",
    "tests/drivers/test_robot_conformance.py",
    "tests/calibration/test_marks.py",
    "tests/daemon/ritad/test_stop_faults.py",
    "tests/system/test_example_config.py",
)


def pytest_collection_modifyitems(config, items) -> None:  # noqa: ANN001 (pytest's hook signature)
    rank = {path: i for i, path in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::", 1)[0], len(rank)))  # stable: the rest as collected
