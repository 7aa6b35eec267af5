"""`make bench`: run every bench/bench_*.py in turn and print their Markdown reports."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> int:
    scripts = sorted(HERE.glob("bench_*.py"))
    only = set(sys.argv[1:])
    failed = []
    for s in scripts:
        if only and s.stem not in only:
            continue
        print(f"\n---- {s.name}", flush=True)
        if subprocess.run([sys.executable, str(s)], cwd=HERE.parent).returncode != 0:
            failed.append(s.name)
    if failed:
        print(f"\nfailed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
