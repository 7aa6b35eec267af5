"""Who may use the console's port: the right Host and Origin, and this launch's secret token.

The console listens on 127.0.0.1, but any page in the operator's browser can make the browser
send requests there, and a DNS-rebinding page can even make them same-origin to its own name.
So every request (the page, its scripts, /files, /list, /api and the WebSocket) must:

* name a loopback host (127.0.0.1, localhost, [::1]) or one given with ``--allow-host``, in
  ``Host`` and, when the browser sends one, in ``Origin``; anything else gets 403;
* carry the per-launch token: ``?token=…`` in the URL ``ritactl console`` prints (as
  Jupyter does), which is then kept in an HttpOnly, SameSite=Strict cookie so the page's
  links, reloads and second tabs work; without it 401.

The token is never logged (the console has no access log).
"""
from __future__ import annotations

import hmac
import secrets
from typing import Any, Awaitable, Callable
from urllib.parse import urlsplit

from aiohttp import web

COOKIE = "rita_console"
LOOPBACK = frozenset({"127.0.0.1", "localhost", "::1"})


def new_token() -> str:
    return secrets.token_urlsafe(24)


def _hostname(value: str) -> str:
    """``host[:port]`` or ``[v6]:port`` → the bare host name, lower case."""
    try:
        return (urlsplit(f"//{value}").hostname or "").lower()
    except ValueError:
        return ""


class Gate:
    """The console's aiohttp middleware: Host/Origin allowlist, then the token."""

    def __init__(self, token: str, allow_hosts: tuple[str, ...] = ()) -> None:
        self.token = token
        self.hosts = LOOPBACK | {h.lower() for h in allow_hosts}

    def _origin_ok(self, origin: str | None) -> bool:
        if origin is None:
            return True  # not a browser's cross-site request (curl, the tests' clients)
        parts = urlsplit(origin)
        return parts.scheme in ("http", "https") and (parts.hostname or "").lower() in self.hosts

    def _token_ok(self, request: web.Request) -> tuple[bool, bool]:
        """(allowed, from the query string: set the cookie)."""
        given = request.query.get("token")
        if given is not None and hmac.compare_digest(given.encode(), self.token.encode()):
            return True, True
        cookie = request.cookies.get(COOKIE)
        return cookie is not None and hmac.compare_digest(cookie.encode(), self.token.encode()), False

    @web.middleware
    async def middleware(self, request: web.Request,
                         handler: Callable[[web.Request], Awaitable[web.StreamResponse]]) -> Any:
        if _hostname(request.host) not in self.hosts or not self._origin_ok(request.headers.get("Origin")):
            return web.Response(status=403,
                                text="forbidden: this console answers only pages it served itself "
                                     "(Host/Origin not allowed; ritactl console --allow-host NAME adds one)")
        ok, from_query = self._token_ok(request)
        if not ok:
            return web.Response(status=401,
                                text="this console needs its token: open the URL `ritactl console` "
                                     "printed (http://127.0.0.1:PORT/?token=...)")
        response = await handler(request)
        if from_query and not response.prepared:
            response.set_cookie(COOKIE, self.token, httponly=True, samesite="Strict", path="/")
        return response
