"""The page's server (see :mod:`fviz.web`): one aiohttp server on one port (``--web-port``), run by an asyncio
loop in one daemon thread of the fviz process:

- ``GET /?token=T``: the page (``page.html``, which hosts rerun-notebook's viewer);
- ``GET /widget.js``, ``/widget.css``, ``/re_viewer_bg.wasm``: the viewer's files, streamed from the installed
  package (sendfile: no copy per client);
- ``GET /ws?token=T``: the WebSocket: the recording's bytes (and a blueprint's) out, the viewer's events (JSON
  texts) in, each click answered with the bytes of its lines (:class:`ClickApp`).

What it protects (docs/interactive.md, "What the page protects, and how"): the recording and the page go only to
a client holding the per-launch secret token of the printed URL (:func:`secrets.token_urlsafe`); every request's
Host must name the bound address and port (a DNS-rebinding page names its own domain); a socket's Origin, when
sent (browsers always send it), must be the page's own (cross-site WebSocket hijacking). Resources are bounded:
client messages (``MAX_MESSAGE`` bytes, text only), open sockets (``MAX_SOCKETS``), a send that takes over
``SEND_TIMEOUT_S`` drops its client, a silent client is dropped by the heartbeat, the events kept per app are few
and cut short; no thread per connection (clicks run on a pool of ``CLICK_THREADS``).
"""

from __future__ import annotations

import asyncio
import collections
import hmac
import html
import ipaddress
import json
import secrets
import socket
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable
from urllib.parse import urlsplit

from fviz.errors import FvizError

PAGE = Path(__file__).with_name("page.html")
TYPES = {".js": "text/javascript", ".wasm": "application/wasm", ".css": "text/css"}
STATIC = ("widget.js", "widget.css", "re_viewer_bg.wasm")
NO_STORE = {"Cache-Control": "no-store"}
# The page: no Referer (its URL holds the token), never framed by another site.
PAGE_HEADERS = {**NO_STORE, "Referrer-Policy": "no-referrer", "Content-Security-Policy": "frame-ancestors 'none'",
                "X-Content-Type-Options": "nosniff"}

MAX_MESSAGE = 1 << 20  # bytes of one client message: the viewer's events are JSON texts of a few kB
MAX_SOCKETS = 8  # pages open at once; more are refused (503)
SEND_TIMEOUT_S = 120.0  # one message (the recording itself: a client that stops reading is dropped)
HEARTBEAT_S = 60.0  # ping after this long without a message; no pong within half of it: dropped
CLICK_THREADS = 2  # the clicks' answers (~3-20 ms each) run off the loop, on these
KEEP_EVENTS, KEEP_EVENT_CHARS = 64, 4096  # ClickApp.events: the last events, each cut to this length
KEEP_TIMINGS = 10_000
LOOPBACK = ("127.0.0.1", "localhost", "::1")
WILDCARD = ("0.0.0.0", "::", "")


def static_dir() -> Path:
    """The viewer's files shipped by ``rerun-notebook`` (widget.js, re_viewer_bg.wasm, widget.css)."""
    import importlib.util

    spec = importlib.util.find_spec("rerun_notebook")
    if spec is None or not spec.origin:
        raise FvizError("the browser viewer needs the package rerun-notebook: pip install 'rerun-sdk[notebook]==0.41.*'")
    return Path(spec.origin).parent / "static"


class ClickApp:
    """What a page gets: the recording's bytes (and a blueprint's) first; then per event JSON string the
    bytes of the click it made, if any (:class:`fviz.interactive.ClickSession`, one per page).

    ``timings``: per click (seconds from the event received to its bytes ready), for the benchmark; ``events``:
    the last ``KEEP_EVENTS`` events received, each cut to ``KEEP_EVENT_CHARS`` (both bounded)."""

    def __init__(self, path: Path, blueprint: Path | None = None, editor=None, export_to: Path | None = None, run=None):
        from fviz.record.reader import store_ids, timelines
        from fviz.record.rebuild import click_pairs, watch_pairs
        from fviz.rerun_compat import check_version

        check_version()  # another rerun: one line when the server starts, not an error per click
        self.path, self.blueprint, self.editor, self.export_to = Path(path), blueprint, editor, export_to
        self.run = run  # the pairs behind the recording, drawn on demand (fviz.api.runpairs): fviz.interactive.OnDemand
        self.ids = store_ids(path)
        self.pairs = click_pairs(path)
        self.watched = {} if self.pairs else watch_pairs(path)  # train.rrd's watched pairs, per step
        self.timelines = timelines(path)
        self.timings: collections.deque[float] = collections.deque(maxlen=KEEP_TIMINGS)
        self.events: collections.deque[str] = collections.deque(maxlen=KEEP_EVENTS)

    def initial(self) -> list[bytes]:
        return [self.path.read_bytes()] + ([Path(self.blueprint).read_bytes()] if self.blueprint else [])

    def new_connection(self) -> tuple[list[str], Callable[[str], list[bytes | str]]]:
        """-> (texts to send first: the edit tools' status when the pair is editable, answer(message) -> what to
        send back: the bytes of a click's or an edit's data, and an edit's status (JSON text))."""
        import rerun as rr

        from fviz.interactive import OnDemand, session_of
        from fviz.rerun_compat import viewer_event_from_json

        rec = rr.RecordingStream(self.ids[0], recording_id=self.ids[1], send_properties=False)
        stream = rec.binary_stream()
        on_demand = OnDemand(rec, self.run) if self.run is not None else None
        session = session_of(rec, self.pairs, self.timelines, self.watched)
        session.on_demand = on_demand
        edits = self.editor(rec, session) if self.editor is not None else None
        hello = [json.dumps({"fviz": "edit", **edits.status(), **self._tools(edits)})] if edits is not None else []

        def answer(text: str) -> list[bytes | str]:
            t0 = time.perf_counter()
            self.events.append(text[:KEEP_EVENT_CHARS])
            command = edit_command(text)
            if command is not None:
                if edits is None:
                    return [json.dumps({"fviz": "error", "error": "this recording cannot be edited here"})]
                if command.get("op") == "box":
                    edits.start_box()
                    return [json.dumps({"fviz": "box", "text": "box: click two corners in one image"})]
                try:
                    reply = {"fviz": "edit", **edits.command(command, self.export_to)}
                except FvizError as exc:
                    reply = {"fviz": "error", "error": str(exc)}
                data = stream.read(flush=True)
                self.timings.append(time.perf_counter() - t0)
                return [b for b in (data,) if b] + [json.dumps(reply, default=str)]
            try:
                event = viewer_event_from_json(text)
            except (ValueError, KeyError):
                return []
            if edits is not None and edits.box is not None and (where := clicked_pixel(event, session)) is not None:
                if edits.corner(*where) is None:
                    return [json.dumps({"fviz": "box", "text": "box: the first corner is set; click the other one in the same image"})]
                data = stream.read(flush=True)
                self.timings.append(time.perf_counter() - t0)
                return [data, json.dumps({"fviz": "edit", **edits.status()})]
            c = session.on_event(event)
            drawn, goto, error = on_demand.take() if on_demand is not None else (False, None, None)
            failed = [json.dumps({"fviz": "error", "error": error})] if error else []
            if c is None and not drawn and goto is None:  # neither a click nor a pair drawn or picked
                return failed
            data = stream.read(flush=True)
            if c is not None:
                self.timings.append(time.perf_counter() - t0)
            clicked = [json.dumps({"fviz": "click", "match": c.match})] if edits is not None and c is not None else []
            moved = [json.dumps({"fviz": "time", "timeline": "pair", "sequence": goto})] if goto is not None else []
            return [b for b in (data,) if b] + clicked + moved + failed

        return hello, answer

    def _tools(self, edits) -> dict:
        """What the page's edit tools offer: the F's to measure residuals under, the robust estimators (threshold,
        iteration cap), whether it can export."""
        from fviz.diagnose import is_robust

        names = [e.name for e in edits.base.estimators if e.F is not None and not e.error]
        robust = [n for n, _ in edits.base._inspected.ests if is_robust(n)]
        return {"fs": names, "robust": robust, "export": self.export_to is not None}


def clicked_pixel(event, session) -> tuple[str, object] | None:
    """(view, pixel) a selection event's position falls on, in the pair at the session's cursor; None otherwise."""
    from fviz.interactive import locate

    fs = session.current()
    for item in getattr(event, "items", None) or () if getattr(event, "type", None) == "selection_change" else ():
        if getattr(item, "type", None) == "entity" and item.position is not None and fs is not None:
            return locate(item.position, fs.size_a, fs.size_b)
    return None


def edit_command(text: str) -> dict | None:
    """The page's edit command in ``text`` (``{"fviz_edit": {"op": ...}}``), None for anything else (a viewer
    event)."""
    if not text.startswith('{"fviz_edit"'):
        return None
    try:
        cmd = json.loads(text).get("fviz_edit")
    except ValueError:
        return None
    return cmd if isinstance(cmd, dict) else None


# ------------------------------------------------------------------------------------------ who may ask


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
        return True
    except ValueError:
        return False


def host_names(bind: str) -> frozenset[str]:
    """The host names a request may name for a server bound to ``bind``: its address (and every loopback name
    when bound to loopback or to every interface; then also this machine's names)."""
    bind = bind.strip("[]").lower()
    names = {bind}
    if bind in LOOPBACK or bind.startswith("127.") or bind in WILDCARD:
        names |= set(LOOPBACK)
    if bind in WILDCARD:
        names |= {socket.gethostname().lower(), socket.getfqdn().lower()}
    return frozenset(names - {""})


def host_allowed(host: str | None, bind: str, port: int) -> bool:
    """Whether a Host header names this server: one of :func:`host_names` (or, bound to every interface, any IP
    literal) and ``port``. Any other name, such as a DNS-rebinding page's domain, is refused."""
    if not host:
        return False
    try:
        parts = urlsplit(f"//{host}")
        name, p = (parts.hostname or "").lower(), parts.port or 80
    except ValueError:  # a port that is no number
        return False
    if p != port:
        return False
    return name in host_names(bind) or (bind.strip("[]") in WILDCARD and _is_ip(name))


def token_ok(given: str | None, token: str) -> bool:
    return given is not None and hmac.compare_digest(given.encode(), token.encode())


def shown_host(bind: str) -> str:
    """The address to print in the URL for a server bound to ``bind``."""
    if bind in ("0.0.0.0", ""):
        return "127.0.0.1"
    if bind == "::":
        return "[::1]"
    return f"[{bind}]" if ":" in bind else bind


# -------------------------------------------------------------------------------------------- the server


class PageServer:
    """The page, the viewer's files and the WebSocket on ``host:port`` (an asyncio loop in one daemon thread)
    until :meth:`close`. ``url``: the page's URL, with the token."""

    def __init__(self, path: Path, host: str = "127.0.0.1", port: int = 9090, blueprint: Path | None = None, editor=None,
                 export_to: Path | None = None, run=None):
        self.app = ClickApp(path, blueprint, editor, export_to, run)
        self.host, self.port = host, port
        self.token = secrets.token_urlsafe(32)
        self.static = static_dir()
        self.page = PAGE.read_text().replace("__TITLE__", html.escape(Path(path).name)).encode()
        self.url = f"http://{shown_host(host)}:{port}/?token={self.token}"
        self.sockets: set = set()
        self.pool = ThreadPoolExecutor(CLICK_THREADS, thread_name_prefix="fviz-click")
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="fviz-web", daemon=True)

    # ---- lifecycle

    def start(self) -> "PageServer":
        """Serve; return once it listens (the bind's error, such as a taken port, is raised here)."""
        self._thread.start()
        self._ready.wait()
        if isinstance(self._error, OSError):  # taken since prepare_serving checked it, or no such address
            raise FvizError(f"--web-port {self.port}: cannot listen on {self.host} ({self._error.strerror or self._error})")
        if self._error is not None:
            raise self._error
        return self

    def close(self) -> None:
        """Close every socket, stop serving and end the loop's thread."""
        loop = self._loop
        if loop is not None and loop.is_running():
            try:
                asyncio.run_coroutine_threadsafe(self._stop(), loop).result(timeout=10)
            except Exception:  # noqa: BLE001 (stopping: whatever is left dies with the thread)
                pass
            loop.call_soon_threadsafe(loop.stop)
        self._thread.join(timeout=10)
        self.pool.shutdown(wait=False, cancel_futures=True)

    def _run(self) -> None:
        self._loop = loop = asyncio.new_event_loop()
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:  # noqa: BLE001 (handed to start())
            self._error = exc
            self._ready.set()
            loop.close()
            return
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            loop.close()

    async def _serve(self) -> None:
        from aiohttp import web

        @web.middleware
        async def check_host(request, handler):
            return await self._check_host(request, handler)

        app = web.Application(middlewares=[check_host], client_max_size=4096)
        app.router.add_get("/", self._page)
        app.router.add_get("/ws", self._socket)
        for name in STATIC:
            app.router.add_get(f"/{name}", self._file)
        self._runner = web.AppRunner(app, handle_signals=False, access_log=None, shutdown_timeout=2,
                                     keepalive_timeout=15)
        await self._runner.setup()
        await web.TCPSite(self._runner, self.host, self.port, reuse_address=True).start()

    async def _stop(self) -> None:
        from aiohttp import WSCloseCode

        closing = [asyncio.ensure_future(ws.close(code=WSCloseCode.GOING_AWAY, message=b"fviz stopped"))
                   for ws in self.sockets]
        if closing:  # all at once, 2 s at most (a page that does not answer is cut by the cleanup)
            await asyncio.wait(closing, timeout=2)
        if self._runner is not None:
            await self._runner.cleanup()

    # ---- requests

    async def _check_host(self, request, handler):
        """Every request (HTTP and WebSocket): its Host names this server, or 403 (DNS rebinding)."""
        from aiohttp import hdrs, web

        if not host_allowed(request.headers.get(hdrs.HOST), self.host, self.port):
            raise web.HTTPForbidden(text="fviz: this server answers only to its own address\n")
        return await handler(request)

    def _refused(self, request, socket_: bool):
        """The error response for a request without the token (or, on the socket, from a foreign page), else None."""
        from aiohttp import hdrs, web

        if not token_ok(request.query.get("token"), self.token):
            return web.HTTPForbidden(text="fviz: open the URL fviz printed, with its token\n")
        origin = request.headers.get(hdrs.ORIGIN)
        if socket_ and origin is not None and origin != f"http://{request.host}":
            return web.HTTPForbidden(text="fviz: foreign origin\n")
        return None

    async def _page(self, request):
        from aiohttp import web

        if (refused := self._refused(request, socket_=False)) is not None:
            raise refused
        return web.Response(body=self.page, content_type="text/html", charset="utf-8", headers=PAGE_HEADERS)

    async def _file(self, request):
        """The viewer's files (public: the package's own), streamed from disk."""
        from aiohttp import web

        name = request.path.lstrip("/")
        return web.FileResponse(self.static / name, headers={**NO_STORE, "Content-Type": TYPES[Path(name).suffix]})

    async def _socket(self, request):
        from aiohttp import web

        if (refused := self._refused(request, socket_=True)) is not None:
            raise refused
        if len(self.sockets) >= MAX_SOCKETS:
            raise web.HTTPServiceUnavailable(text=f"fviz: {MAX_SOCKETS} pages are open already\n")
        ws = web.WebSocketResponse(max_msg_size=MAX_MESSAGE, heartbeat=HEARTBEAT_S, compress=False)
        self.sockets.add(ws)
        try:
            await ws.prepare(request)
            await self._talk(ws, request)
        finally:
            self.sockets.discard(ws)
        return ws

    async def _talk(self, ws, request) -> None:
        """The recording out, then the events in and their answers out, until either side closes."""
        from aiohttp import WSCloseCode, WSMsgType

        loop = asyncio.get_running_loop()
        for blob in await loop.run_in_executor(self.pool, self.app.initial):
            if not await self._send(ws, request, blob):
                return
        hello, answer = await loop.run_in_executor(self.pool, self.app.new_connection)
        for text in hello:
            if not await self._send(ws, request, text):
                return
        async for msg in ws:  # a message over MAX_MESSAGE: aiohttp closes the socket (1009)
            if msg.type == WSMsgType.BINARY:
                await ws.close(code=WSCloseCode.UNSUPPORTED_DATA, message=b"text messages only")
                return
            if msg.type == WSMsgType.TEXT:
                for out in await loop.run_in_executor(self.pool, answer, msg.data):
                    if not await self._send(ws, request, out):
                        return

    @staticmethod
    async def _send(ws, request, data: bytes | str) -> bool:
        """Send, or drop a client that does not read it within SEND_TIMEOUT_S (or is gone): whether it was sent."""
        try:
            sent = ws.send_str(data) if isinstance(data, str) else ws.send_bytes(data)
            await asyncio.wait_for(sent, SEND_TIMEOUT_S)
            return True
        except (asyncio.TimeoutError, ConnectionError):
            if request.transport is not None:
                request.transport.abort()
            return False


def serve_clicks(path: Path, host: str = "127.0.0.1", web_port: int = 9090, blueprint: Path | None = None, editor=None,
                 export_to: Path | None = None, run=None) -> None:
    """Serve the clickable page until Ctrl-C, SIGTERM or SIGHUP; print its URL once it serves. ``editor(rec,
    clicks) -> EditSession`` makes each page's edit tools (:mod:`fviz.editing`); ``export_to``: their export folder;
    ``run``: the pairs of the run whose eval.rrd this is, drawn when the time cursor reaches one (ClickApp)."""
    from fviz.viewer import prepare_serving

    prepare_serving(path, host, None, web_port)
    server = PageServer(path, host, web_port, blueprint, editor, export_to, run).start()
    try:
        what = "; edit the matches with the tools at the top" if editor is not None else ""
        what += f"; {run.hint}" if run is not None else ""
        hint = (f"click a point of either image for its epipolar lines{what}" if server.app.pairs or run is not None else
                "click a point of a watched pair for its epipolar lines under the ground truth, the network at the time "
                "cursor's step and the baseline" if server.app.watched else
                "no pair images in this recording, nothing to click: eval --full records them")
        print(f"web viewer: {server.url}  ({hint}; Ctrl-C to stop)", flush=True)
        while True:  # short naps: a signal the kernel hands to a server thread only wakes the main one at its next tick
            time.sleep(0.2)
    except KeyboardInterrupt:
        print("web viewer stopped", file=sys.stderr)
    finally:
        server.close()
