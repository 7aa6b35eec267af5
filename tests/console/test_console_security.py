"""The console's port answers only its own pages: Host/Origin allowlist (DNS rebinding) and the launch token.

The web app runs in-process on 127.0.0.1:0 in front of a simulated ritad (no browser needed).
"""
from __future__ import annotations

import asyncio
import contextlib
from pathlib import Path
from typing import AsyncIterator

import pytest

pytest.importorskip("aiohttp")

from daemon.bus.client import Client  # noqa: E402
from tests.ctl_sim import sim_daemon  # noqa: E402


@pytest.fixture(scope="module")
def endpoint(tmp_path_factory):
    with sim_daemon(tmp_path_factory.mktemp("consec")) as d:
        yield d.server.endpoints[0]


@contextlib.asynccontextmanager
async def console(endpoint: str, tmp: Path, **kw) -> AsyncIterator[tuple[str, str]]:
    """(base URL, token) of the console's app served in this loop."""
    from aiohttp import web

    from daemon.console.bridge import Bridge
    from daemon.console.server import Console

    bridge = Bridge(lambda: Client(endpoint, timeout=10))
    await asyncio.get_running_loop().run_in_executor(None, bridge.start)
    con = Console(bridge, tmp, **kw)
    runner = web.AppRunner(con.app(), access_log=None)
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    try:
        yield f"http://127.0.0.1:{runner.addresses[0][1]}/", con.token
    finally:
        con.survey.close()
        await runner.cleanup()
        bridge.stop()


async def status(url: str, headers: dict[str, str] | None = None, cookie_jar=None) -> int:
    import aiohttp

    async with aiohttp.ClientSession(cookie_jar=cookie_jar) as http:
        async with http.get(url, headers=headers or {}, allow_redirects=False) as r:
            return r.status


def test_rebinding_and_tokenless_requests_are_refused_and_the_genuine_page_works(endpoint, tmp_path):
    import aiohttp

    async def main() -> None:
        async with console(endpoint, tmp_path) as (base, token):
            port = base.rsplit(":", 1)[1].strip("/")
            evil = {"Host": f"evil.example:{port}", "Origin": f"http://evil.example:{port}"}
            for path in ("", "files/x", "list/", "api/info", "ws"):
                assert await status(f"{base}{path}?token={token}", evil) == 403, path
                assert await status(f"{base}{path}", {"Origin": f"http://evil.example:{port}"}) == 403, path
                assert await status(f"{base}{path}") == 401, path  # no token
                assert await status(f"{base}{path}?token=wrong") == 401, path
            assert await status(f"{base}?token={token}") == 200
            assert await status(f"{base}api/info?token={token}", {"Origin": base.rstrip("/")}) == 200
            jar = aiohttp.CookieJar(unsafe=True)  # 127.0.0.1: keep the cookie as a browser does
            async with aiohttp.ClientSession(cookie_jar=jar) as http:
                async with http.get(f"{base}?token={token}") as r:
                    assert r.status == 200
                async with http.get(f"{base}api/info") as r:  # a link or reload: the cookie carries it
                    assert r.status == 200
                async with http.ws_connect(f"{base}ws") as ws:
                    assert (await ws.receive_json(timeout=10))["type"] == "hello"

    asyncio.run(main())


def test_allowed_hosts_are_configurable(endpoint, tmp_path):
    async def main() -> None:
        async with console(endpoint, tmp_path, allow_hosts=("rita-laptop",)) as (base, token):
            port = base.rsplit(":", 1)[1].strip("/")
            assert await status(f"{base}api/info?token={token}", {"Host": f"rita-laptop:{port}"}) == 200
            assert await status(f"{base}api/info?token={token}", {"Host": f"rita-laptop.evil:{port}"}) == 403

    asyncio.run(main())
