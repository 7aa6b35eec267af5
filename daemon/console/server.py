"""``ritactl console``: the operator console, a local web page in front of the robot's bus.

aiohttp serves the static page and one WebSocket per tab on 127.0.0.1 only. The
page pulls camera pictures (it sends ``next`` after drawing one; the console then
pulls a small JPEG of the newest frame with ``camera.preview``, so a slow tab just gets
fewer pictures, each the newest, and costs the robot nothing while it lags) and receives telemetry as the
latest value per topic every ``STATE_PERIOD_S`` (coalesced: a slow tab skips intermediate values but
always ends on the current state) plus the calibration and motion events in order.
Commands from the page go to the bus unchanged; the daemon checks the key's role,
and the page disables what the role may not send. The WebSocket protocol is in
docs/operations.md, "Operator console".
"""
from __future__ import annotations

import asyncio
import html
import json
import logging
import mimetypes
import time
from concurrent.futures import Executor
from pathlib import Path
from typing import Any, Callable, Coroutine, TypedDict
from urllib.parse import quote

from aiohttp import WSMsgType, web

from daemon import __version__
from daemon.bus.client import ClientTimeout
from daemon.bus.command_table import COMMANDS, ROLES
from daemon.bus.procedures import PROCEDURES, describe as procedure_info, schema as procedure_schema
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.bus.storage import atomic_write_bytes
from daemon.console.bridge import Bridge
from daemon.console.gate import Gate, new_token
from daemon.console.jobs import start_job
from daemon.console.series import SERIES
from daemon.console.survey import Survey, read_plate_file
from daemon.bus.png_write import frame_png

log = logging.getLogger(__name__)
STATIC = Path(__file__).parent / "static"
STATE_PERIOD_S = 0.2          # telemetry push period: 5 updates/s is smooth for numbers and cheap
MAX_FPS = 30.0                # the page may ask for fewer; never more than a browser can show usefully


class View(TypedDict):
    """What a tab asked to see: picture width (px), frames per second, region (x, y, w, h) or the whole."""

    width: int
    fps: float
    roi: tuple[int, ...] | None


DEFAULT_VIEW: View = {"width": 640, "fps": 5.0, "roi": None}
#: commands a page may send: everything an operator or viewer uses, never the worker's own
PAGE_COMMANDS = sorted(n for n, c in COMMANDS.items() if not c.worker_only)


def _error(exc: BaseException) -> dict[str, str]:
    if isinstance(exc, CommandError):  # ``field``: the form field a bad procedure parameter came from
        message = exc.args[0] if exc.args else exc.code
        return {"code": exc.code, "message": message, "field": getattr(exc, "field", "")}
    return {"code": "internal", "message": f"{type(exc).__name__}: {exc}"}


class Tab:
    """One WebSocket: its view settings, its frame credit and what it has already seen."""

    def __init__(self, ws: web.WebSocketResponse) -> None:
        self.ws = ws
        self.view: View = {**DEFAULT_VIEW}
        self.credit = asyncio.Event()
        self.credit.set()
        self.seen: dict[str, int] = {}
        self.event_no = 0
        self.frame_id = -1  # the newest frame this tab has (camera.preview's ``after``)
        self.sent_at = 0.0
        self.preview_error = ""
        self.survey_version = -1  # the survey state this tab has
        self.series_no = 0  # the last plotted point this tab has (daemon/console/series.py)


class Console:
    def __init__(self, bridge: Bridge, captures: Path, token: str | None = None,
                 allow_hosts: tuple[str, ...] = ()) -> None:
        self.bridge = bridge
        self.captures = captures
        self.tabs: set[Tab] = set()
        self.frames_sent = 0
        self.survey = Survey()
        self.gate = Gate(token or new_token(), allow_hosts)
        self._tasks: set[asyncio.Task[None]] = set()  # the page's commands in flight

    def _spawn(self, work: Coroutine[Any, Any, None]) -> None:
        """Run ``work`` as a task, holding it until it ends (the event loop keeps only weak references)."""
        task = asyncio.create_task(work)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    @property
    def token(self) -> str:
        return self.gate.token

    # ------------------------------------------------------------------ http
    def app(self) -> web.Application:
        app = web.Application(client_max_size=1 << 20, middlewares=[self.gate.middleware])
        app.router.add_get("/", self.index)
        app.router.add_get("/ws", self.websocket)
        app.router.add_get("/files/{path:.+}", self.download)
        app.router.add_get("/list/{path:.*}", self.listing)
        app.router.add_get("/api/info", self.info)
        app.router.add_static("/static/", STATIC, show_index=False)
        return app

    async def index(self, _: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    async def info(self, _: web.Request) -> web.Response:
        return web.json_response(self.info_payload())

    def info_payload(self) -> dict[str, Any]:
        b = self.bridge
        return {"console": __version__, "role": b.role, "roles": list(ROLES), "procedures": list(PROCEDURES),
                "procedure_params": procedure_schema(), "procedure_info": procedure_info(),
                "commands": {n: COMMANDS[n].role for n in PAGE_COMMANDS}, "daemon": b.hello,
                "frames_sent": self.frames_sent, "tabs": len(self.tabs),
                "series": {name: [list(v) for v in values] for name, values in SERIES.items()}}

    async def listing(self, request: web.Request) -> web.Response:
        """A data-dir folder (a dataset) as a page of download links (files.list)."""
        path = request.match_info["path"]
        args = {"path": path} if path else {}
        try:
            r = await asyncio.get_running_loop().run_in_executor(
                self.bridge.pool, self.bridge.call, "files.list", args, 30.0)
        except (CommandError, ClientTimeout) as exc:
            return web.Response(status=404, text=f"{path}: {_error(exc)['message']}")
        rows = "".join(f'<li><a href="/files/{quote(f["path"])}?download=1">{html.escape(f["path"])}</a> '
                       f'{f["size"]} B</li>' for f in r["files"])
        more = "<p>(list truncated)</p>" if r.get("truncated") else ""
        page = (f"<!doctype html><meta charset=utf-8><title>{html.escape(path)}</title>"
                f"<h1>{html.escape(path or 'data dir')}</h1><ul>{rows}</ul>{more}")
        return web.Response(content_type="text/html", text=page)

    async def download(self, request: web.Request) -> web.StreamResponse:
        """A data-dir file of the robot (dataset, report, plot), copied chunk by chunk with files.read."""
        path = request.match_info["path"]
        loop = asyncio.get_running_loop()
        resp = web.StreamResponse()
        ctype = mimetypes.guess_type(path)[0] or "application/octet-stream"
        resp.content_type = ctype
        if request.query.get("download"):
            resp.headers["Content-Disposition"] = f'attachment; filename="{Path(path).name}"'
        offset, started = 0, False
        while True:
            try:
                meta, data = await loop.run_in_executor(self.bridge.pool, self.bridge.call_raw, "files.read",
                                                        {"path": path, "offset": offset}, 30.0)
            except (CommandError, ClientTimeout) as exc:
                if started:
                    raise  # a half-sent file: the browser sees a broken download, never a wrong one
                status = 404 if getattr(exc, "code", "") in ("not_found", "bad_args") else 502
                return web.Response(status=status, text=f"{path}: {_error(exc)['message']}")
            if not started:
                resp.content_length = meta["size"]
                await resp.prepare(request)
                started = True
            if data:
                await resp.write(data[0])
                offset += len(data[0])
            if meta.get("eof") or not data or not data[0]:
                break
        await resp.write_eof()
        return resp

    # ------------------------------------------------------------------ websocket
    async def websocket(self, request: web.Request) -> web.StreamResponse:
        origin = request.headers.get("Origin")
        if origin and origin.split("://", 1)[-1] != request.host:
            # another site open in the same browser must not drive the robot through this port
            return web.Response(status=403, text=f"origin {origin} may not use this console")
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=1 << 20)
        await ws.prepare(request)
        tab = Tab(ws)
        self.tabs.add(tab)
        await ws.send_json({"type": "hello", **self.info_payload()})
        tasks = [asyncio.create_task(self._push_state(tab)), asyncio.create_task(self._push_frames(tab))]
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                try:
                    req = json.loads(msg.data)
                    if not isinstance(req, dict):
                        raise ValueError("not an object")
                except ValueError as exc:
                    await ws.send_json({"type": "error", "message": f"bad message from the page: {exc}"})
                    continue
                self._handle(tab, req)
        finally:
            for t in tasks:
                t.cancel()
            self.tabs.discard(tab)
        return ws

    def _handle(self, tab: Tab, req: dict[str, Any]) -> None:
        op = req.get("op")
        if op == "next":
            tab.credit.set()
        elif op == "view":
            tab.view = _checked_view(req)
            tab.frame_id = -1  # a new size or region: send the current picture again
        elif op == "call":
            self._spawn(self._call(tab, req))
        elif op == "capture":
            self._spawn(self._capture(tab, req))
        elif op == "survey":
            self._spawn(self._survey(tab, req))

    async def _reply(self, tab: Tab, req: dict[str, Any], fn: Callable[..., Any], *args: Any,
                     pool: Executor | None = None) -> None:
        try:
            result = await asyncio.get_running_loop().run_in_executor(pool or self.bridge.pool, fn, *args)
            msg = {"type": "reply", "id": req.get("id"), "ok": True, "result": result}
        except Exception as exc:  # noqa: BLE001 - any failure goes to the page, the console keeps serving
            msg = {"type": "reply", "id": req.get("id"), "ok": False, "error": _error(exc)}
        if not tab.ws.closed:
            await tab.ws.send_str(json.dumps(msg, default=str))

    async def _call(self, tab: Tab, req: dict[str, Any]) -> None:
        cmd, args = req.get("cmd"), req.get("args") or {}
        if cmd not in PAGE_COMMANDS or not isinstance(args, dict):
            err = {"code": "bad_args",
                   "message": f"the console does not send {cmd!r} (or its args are not a map)"}
            await tab.ws.send_json({"type": "reply", "id": req.get("id"), "ok": False, "error": err})
            return
        timeout = req.get("timeout")
        timeout = float(timeout) if isinstance(timeout, (int, float)) and 0 < timeout <= 600 else 30.0
        if cmd == "calib.start":  # the page's form values, checked again and its files read on the robot
            await self._reply(tab, req, start_job, self.bridge, args, timeout)
            return
        pool = self.bridge.urgent if cmd == "robot.stop" else None
        await self._reply(tab, req, self.bridge.call, cmd, args, timeout, pool=pool)

    async def _survey(self, tab: Tab, req: dict[str, Any]) -> None:
        """Start, cancel or upload the laptop's plate survey (daemon/console/survey.py); operators only."""
        try:
            role = self.bridge.role
            if role not in ROLES or ROLES.index(role) < ROLES.index("operator"):
                raise CommandError(ErrorCode.FORBIDDEN, "the plate survey is an operator's control; "
                                   f"this console's key has the role {role!r}")
            action = req.get("action")
            if action == "upload":  # a local plate file to the robot's calibration folder (the daemon checks)
                args = {"plate": read_plate_file(req.get("out")), "name": req.get("name") or "plate.json"}
                result = await asyncio.get_running_loop().run_in_executor(self.bridge.pool, self.bridge.call,
                                                                          "calib.plate.upload", args, 30.0)
            else:
                result = self.survey.cancel() if action == "cancel" else await self.survey.start(req)
            msg = {"type": "reply", "id": req.get("id"), "ok": True, "result": result}
        except Exception as exc:  # noqa: BLE001 - any failure goes to the page, the console keeps serving
            err = _error(exc) if not isinstance(exc, OSError) else {"code": "failed", "message": str(exc)}
            msg = {"type": "reply", "id": req.get("id"), "ok": False, "error": err}
        if not tab.ws.closed:
            await tab.ws.send_json(msg)

    async def _capture(self, tab: Tab, req: dict[str, Any]) -> None:
        await self._reply(tab, req, self._capture_sync, str(req.get("label") or "frame"))

    def _capture_sync(self, label: str) -> dict[str, Any]:
        """A full-resolution frame from the robot (also stored there), saved as PNG on this laptop."""
        args = {"pixels": True, "save": True, "label": label}
        result, frames = self.bridge.call_raw("camera.capture", args, 60.0)
        header = result["header"]
        png = frame_png(header, frames[0])  # at the frame's own depth and channels, as ritactl capture --out
        safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in label)[:40] or "frame"
        path = self.captures / f"{time.strftime('%Y%m%d-%H%M%S')}-{safe}-{header.get('frame_id', 0)}.png"
        atomic_write_bytes(path, png)
        return {"saved": str(path), "robot_path": result.get("path"), "header": header}

    async def _push_state(self, tab: Tab) -> None:
        while not tab.ws.closed:
            topics = self.bridge.state_since(tab.seen)
            events = self.bridge.events_since(tab.event_no)
            if events:
                tab.event_no = events[-1]["no"]
            series = self.bridge.series.since(tab.series_no)
            if series:
                tab.series_no = series[-1]["no"]
            msg = {"type": "state", "topics": topics, "events": events, "series": series,
                   "link": self.bridge.link,
                   "console": {"frames_sent": self.frames_sent, "tabs": len(self.tabs),
                               "preview_error": tab.preview_error}}
            if tab.survey_version != self.survey.state["version"]:  # only when it changed: a report is large
                msg["survey"] = self.survey.state
                tab.survey_version = self.survey.state["version"]
            await tab.ws.send_str(json.dumps(msg, default=str))
            await asyncio.sleep(STATE_PERIOD_S)

    async def _push_frames(self, tab: Tab) -> None:
        """Pull ``camera.preview`` for this tab when it has asked for a picture and its rate allows one."""
        loop = asyncio.get_running_loop()
        while not tab.ws.closed:
            await tab.credit.wait()
            wait = tab.sent_at + 0.9 / tab.view["fps"] - time.monotonic()  # 0.9: jitter never halves the rate
            if wait > 0:
                await asyncio.sleep(wait)
            roi = tab.view["roi"]
            args = {"width": tab.view["width"], "after": tab.frame_id,
                    **(dict(zip(("roi_x", "roi_y", "roi_w", "roi_h"), roi)) if roi else {})}
            try:
                meta, parts = await loop.run_in_executor(
                    self.bridge.pool, self.bridge.call_raw, "camera.preview", args, 10.0)
            except (CommandError, ClientTimeout) as exc:  # no stream yet, camera gone, link down: retry later
                tab.preview_error = _error(exc)["message"]
                await asyncio.sleep(0.5)
                continue
            if meta.get("unchanged"):
                await asyncio.sleep(0.05)
                continue
            tab.preview_error = ""
            header = meta.pop("header")
            tab.credit.clear()
            tab.frame_id, tab.sent_at = header["frame_id"], time.monotonic()
            head = {k: header.get(k) for k in ("frame_id", "exposure_us", "gain_db", "host_time_ns",
                                               "pixel_format")}
            await tab.ws.send_json({"type": "frame", **head, **meta, "console_tx_ns": time.time_ns()})
            await tab.ws.send_bytes(parts[0])
            self.frames_sent += 1


def _checked_view(req: dict[str, Any]) -> View:
    """The page's view request, clamped to what the console serves."""
    out: View = {**DEFAULT_VIEW}
    w, fps, roi = req.get("width"), req.get("fps"), req.get("roi")
    if isinstance(w, (int, float)) and w > 0:
        out["width"] = int(min(max(w, 16), 4096))
    if isinstance(fps, (int, float)) and fps > 0:
        out["fps"] = float(min(fps, MAX_FPS))
    if isinstance(roi, list) and len(roi) == 4 and all(isinstance(v, (int, float)) for v in roi):
        out["roi"] = tuple(int(v) for v in roi)
    return out


async def serve(bridge: Bridge, port: int, captures: Path, on_ready: Callable[[str], object] | None = None,
                duration: float | None = None, allow_hosts: tuple[str, ...] = (),
                token: str | None = None) -> None:
    """Serve until cancelled (or ``duration`` s); ``on_ready(url)`` once the port is bound (0: a free one).

    The URL carries this launch's secret token (docs/operations.md, "Operator console": security)."""
    console = Console(bridge, captures, token=token, allow_hosts=allow_hosts)
    runner = web.AppRunner(console.app(), access_log=None)
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", port)  # the laptop's own browser only
    await site.start()
    bound = runner.addresses[0][1]
    if on_ready is not None:
        on_ready(f"http://127.0.0.1:{bound}/?token={console.token}")
    try:
        if duration is None:
            await asyncio.Event().wait()
        else:
            await asyncio.sleep(duration)
    finally:
        console.survey.close()
        await runner.cleanup()
