"""Start the console: bus bridge first (a dead daemon or refused key fails before any port opens),
then HTTP."""
from __future__ import annotations

import asyncio
import sys
import webbrowser
from pathlib import Path
from typing import Any, Callable

from daemon.bus.client import Client


def run(make_client: Callable[[], Client], port: int, captures: Path, open_browser: bool = False,
        say: Callable[[str], Any] = print, duration: float | None = None, allow_hosts: tuple[str, ...] = (),
        token: str | None = None) -> int:
    """Serve the console until Ctrl-C (or ``duration`` s); raises ClientTimeout/CommandError when the
    daemon cannot be used."""
    from daemon.console.bridge import Bridge
    from daemon.console.server import serve

    bridge = Bridge(make_client)
    bridge.start()

    def ready(url: str) -> None:
        say(f"ritactl console: {url} (role {bridge.role}; Ctrl-C stops)")
        sys.stdout.flush()
        if open_browser:
            webbrowser.open(url)

    try:
        asyncio.run(serve(bridge, port, captures, ready, duration, allow_hosts, token))
    finally:
        bridge.stop()
    return 0
