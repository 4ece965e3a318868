"""The page's two servers (see :mod:`fviz.web`): HTTP for the page and the viewer's files, and a minimal
WebSocket (RFC 6455: one unfragmented message per frame, which is what browsers send for short texts) for
the recording's bytes, the viewer's events and the clicks' answers. Standard library only."""

from __future__ import annotations

import base64
import hashlib
import http.server
import socketserver
import struct
import sys
import threading
import time
from pathlib import Path

from fviz.errors import FvizError

_GUID = b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11"
PAGE = Path(__file__).with_name("page.html")
TYPES = {".js": "text/javascript", ".wasm": "application/wasm", ".css": "text/css", ".html": "text/html; charset=utf-8"}


def static_dir() -> Path:
    """The viewer's files shipped by ``rerun-notebook`` (widget.js, re_viewer_bg.wasm, widget.css)."""
    import importlib.util

    spec = importlib.util.find_spec("rerun_notebook")
    if spec is None or not spec.origin:
        raise FvizError("the browser viewer needs the package rerun-notebook: pip install 'rerun-sdk[notebook]==0.41.*'")
    return Path(spec.origin).parent / "static"


def accept_key(key: str) -> str:
    """Sec-WebSocket-Accept for a Sec-WebSocket-Key."""
    return base64.b64encode(hashlib.sha1(key.strip().encode() + _GUID).digest()).decode()


def frame(payload: bytes, opcode: int) -> bytes:
    """One unmasked, final server frame."""
    n = len(payload)
    head = bytes([0x80 | opcode])
    if n < 126:
        head += bytes([n])
    elif n < 1 << 16:
        head += bytes([126]) + struct.pack(">H", n)
    else:
        head += bytes([127]) + struct.pack(">Q", n)
    return head + payload


def read_frame(f) -> tuple[int, bytes] | None:
    """(opcode, unmasked payload) of the next frame from a file-like socket, None at EOF."""
    head = f.read(2)
    if len(head) < 2:
        return None
    op, n = head[0] & 0x0F, head[1] & 0x7F
    if n == 126:
        n = struct.unpack(">H", f.read(2))[0]
    elif n == 127:
        n = struct.unpack(">Q", f.read(8))[0]
    mask = f.read(4) if head[1] & 0x80 else None
    data = f.read(n)
    if mask:
        import numpy as np

        data = (np.frombuffer(data, np.uint8) ^ np.resize(np.frombuffer(mask, np.uint8), n)).tobytes()
    return op, data


class _Page(http.server.BaseHTTPRequestHandler):
    server_version = "fviz"

    def do_GET(self):  # noqa: N802 (http.server's name)
        name = self.path.split("?")[0].lstrip("/") or "index.html"
        if name == "index.html":
            body = self.server.page  # type: ignore[attr-defined]
        elif name in ("widget.js", "widget.css", "re_viewer_bg.wasm"):
            body = (self.server.static / name).read_bytes()  # type: ignore[attr-defined]
        else:
            self.send_error(404)
            return
        self.send_response(200)
        self.send_header("Content-Type", TYPES[Path(name).suffix])
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):  # quiet
        pass


class _Socket(socketserver.StreamRequestHandler):
    """One page: the recording's bytes, then the viewer's events in and the clicks' bytes out."""

    def handle(self):
        headers = {}
        self.rfile.readline()
        while (line := self.rfile.readline().decode("latin-1").strip()):
            k, _, v = line.partition(":")
            headers[k.strip().lower()] = v.strip()
        if "sec-websocket-key" not in headers:
            self.wfile.write(b"HTTP/1.1 426 Upgrade Required\r\nContent-Length: 0\r\n\r\n")
            return
        self.wfile.write(("HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                          f"Sec-WebSocket-Accept: {accept_key(headers['sec-websocket-key'])}\r\n\r\n").encode())
        app = self.server.app  # type: ignore[attr-defined]
        for blob in app.initial():
            self.wfile.write(frame(blob, 0x2))
        answer = app.new_connection()
        while (msg := read_frame(self.rfile)) is not None:
            op, data = msg
            if op == 0x8:
                self.wfile.write(frame(data[:2], 0x8))
                return
            if op == 0x9:
                self.wfile.write(frame(data, 0xA))
            elif op == 0x1:
                out = answer(data.decode("utf-8", "replace"))
                if out:
                    self.wfile.write(frame(out, 0x2))


class _Threading(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, host: str, port: int, handler):
        import socket

        self.address_family = socket.AF_INET6 if ":" in host else socket.AF_INET
        super().__init__((host, port), handler)

    def handle_error(self, request, client_address):
        """A page closed or reloaded mid-transfer is no error; anything else is printed as usual."""
        if not isinstance(sys.exc_info()[1], (ConnectionError, TimeoutError)):
            super().handle_error(request, client_address)


class ClickApp:
    """What a page gets: the recording's bytes (and a blueprint's) first; then per event JSON string the
    bytes of the click it made, if any (:class:`fviz.interactive.ClickSession`, one per page).

    ``timings``: per click (seconds from the event received to its bytes ready), for the benchmark."""

    def __init__(self, path: Path, blueprint: Path | None = None):
        from fviz.record.reader import click_pairs, store_ids, timelines
        from fviz.record import layout as L

        self.path, self.blueprint = Path(path), blueprint
        self.ids = store_ids(path)
        self.pairs = click_pairs(path)
        self.stamps = tuple(t for t in timelines(path) if t == L.PROBE_TIMELINE)
        self.timings: list[float] = []
        self.events: list[str] = []

    def initial(self) -> list[bytes]:
        return [self.path.read_bytes()] + ([Path(self.blueprint).read_bytes()] if self.blueprint else [])

    def new_connection(self):
        """-> answer(event JSON) -> bytes of the click's data, or None."""
        import rerun as rr
        from rerun._event import _viewer_event_from_json_str

        from fviz.interactive import ClickSession

        rec = rr.RecordingStream(self.ids[0], recording_id=self.ids[1], send_properties=False)
        stream = rec.binary_stream()
        session = ClickSession(rec, self.pairs, self.stamps)

        def answer(text: str) -> bytes | None:
            t0 = time.perf_counter()
            self.events.append(text)
            try:
                event = _viewer_event_from_json_str(text)
            except (ValueError, KeyError):
                return None
            if session.on_event(event) is None:
                return None
            data = stream.read(flush=True)
            self.timings.append(time.perf_counter() - t0)
            return data

        return answer


class ClickServer:
    """Both servers on ``host``: the page on ``web_port``, the WebSocket on ``port`` (threads of this process)."""

    def __init__(self, path: Path, host: str = "127.0.0.1", port: int = 9876, web_port: int = 9090,
                 blueprint: Path | None = None):
        self.app = ClickApp(path, blueprint)
        self.ws = _Threading(host, port, _Socket)
        self.ws.app = self.app  # type: ignore[attr-defined]
        self.http = _Threading(host, web_port, _Page)
        self.http.static = static_dir()  # type: ignore[attr-defined]
        self.http.page = PAGE.read_text().replace("__WS_PORT__", str(port)).replace(  # type: ignore[attr-defined]
            "__TITLE__", Path(path).name).encode()
        shown = "127.0.0.1" if host in ("0.0.0.0", "::", "") else f"[{host}]" if ":" in host else host
        self.url = f"http://{shown}:{web_port}/?recording=ws://{shown}:{port}"
        self._threads = [threading.Thread(target=s.serve_forever, daemon=True) for s in (self.ws, self.http)]

    def start(self) -> "ClickServer":
        for t in self._threads:
            t.start()
        return self

    def close(self) -> None:
        for s in (self.ws, self.http):
            s.shutdown()
            s.server_close()


def serve_clicks(path: Path, host: str = "127.0.0.1", port: int = 9876, web_port: int = 9090,
                 blueprint: Path | None = None) -> None:
    """Serve the clickable page until Ctrl-C, SIGTERM or SIGHUP; print its URL once it serves."""
    from fviz.viewer import prepare_serving

    prepare_serving(path, host, port, web_port)
    server = ClickServer(path, host, port, web_port, blueprint).start()
    try:
        print(f"web viewer: {server.url}  (click a point of either image for its epipolar lines; Ctrl-C to stop)",
              flush=True)
        while True:  # short naps: a signal the kernel hands to a server thread only wakes the main one at its next tick
            time.sleep(0.2)
    except KeyboardInterrupt:
        print("web viewer stopped", file=sys.stderr)
    finally:
        server.close()
