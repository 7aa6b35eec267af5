import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

# ritad registers the installed plugins' commands (the simulator's sim.*) when it loads its config;
# registering them here, before any test module reads the table, lets every test see the table as a
# running ritad does, whatever ran earlier in the same worker.
from daemon.ritad.plugins import installed  # noqa: E402

installed()
