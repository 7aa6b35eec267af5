"""``ritactl console``: serve the operator console on 127.0.0.1 (docs/operations.md, "Operator console")."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from daemon.bus.client import Client
from daemon.ctl.exitcodes import CtlError, Exit
from daemon.ctl.extras import CONSOLE, require


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 0 <= value < 65536:
        raise argparse.ArgumentTypeError(f"port {value} is outside 0..65535 (0: any free port)")
    return value


def cmd_console(c: Client, a: argparse.Namespace) -> int:
    require("ritactl console", CONSOLE)  # the thin client without the console extra: exit 5 naming it
    from daemon.console.run import run

    if a.duration is not None and not 0 < a.duration < 1e7:
        raise CtlError(Exit.USAGE, "usage",
                       f"console: --duration {a.duration:g} must be between 0 and 1e7 seconds")

    def make_client() -> Client:
        return Client(c.endpoint, timeout=c.timeout, curve=c.curve, key_id=c.key_id)

    try:
        return run(make_client, a.port, Path(a.captures).expanduser(), a.open, duration=a.duration,
                   allow_hosts=tuple(a.allow_host or ()), token=a.token)
    except OSError as exc:
        if exc.errno in (98, 10048):  # EADDRINUSE (Linux, Windows)
            raise CtlError(Exit.USAGE, "usage", f"port {a.port} on 127.0.0.1 is in use: choose another "
                                                f"with --port (0: any free port)") from None
        raise
    except KeyboardInterrupt:
        return Exit.OK


def add_parser(sub: Any) -> None:
    p = sub.add_parser("console", help="operator console in the browser (http://127.0.0.1:PORT)",
                       description="Serve the operator console on 127.0.0.1 for this computer's browser: "
                                   "live camera, tracker/robot/daemon panels, STOP, procedures, results. "
                                   "Runs until Ctrl-C. The URL it prints carries this launch's secret token "
                                   "(needed by the page). Needs pip install 'rita[console]'.")
    p.add_argument("--port", type=_port, default=8765,
                   help="TCP port on 127.0.0.1 (default 8765; 0: any free)")
    p.add_argument("--captures", default="rita-captures", metavar="DIR",
                   help="folder for frames captured from the page (default ./rita-captures)")
    p.add_argument("--open", action="store_true", help="open the page in the default browser")
    p.add_argument("--duration", type=float, metavar="S",
                   help="stop after S seconds (default: run until Ctrl-C)")
    p.add_argument("--token", help="use this token instead of a new one (a restarted console that open pages "
                                   "reconnect to); the default is a new secret token per launch")
    p.add_argument("--allow-host", action="append", metavar="NAME",
                   help="a host name the page may be opened under besides 127.0.0.1/localhost (repeatable; "
                        "anything else is refused with 403)")
    p.set_defaults(fn=cmd_console)
