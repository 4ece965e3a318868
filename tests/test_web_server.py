"""fviz's page server (``fviz open FILE --web``, fviz/web/server.py) against clients it must refuse or outlast:
no token or a wrong one, a foreign Origin (cross-site WebSocket hijacking), a Host that is not the server's (DNS
rebinding), oversized and malformed frames, many idle connections, slow downloads of the 65 MB viewer. Real
server on a free port, real clients (http.client, websocket-client, raw sockets); the recording's bytes must never
reach a refused client. What a page gets when allowed: tests/test_interactive.py (the socket), the browser tests."""

from __future__ import annotations

import base64
import http.client
import os
import signal
import socket
import struct
import threading
import time

import pytest
import websocket
from browser import WebServer, free_port, run_fviz

from fviz.web import server as S

WASM = "/re_viewer_bg.wasm"


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("web") / "p.rrd"
    r = run_fviz("inspect", "pair", "--synthetic", "--seed", "0", "-e", "8point", "--out", path)
    assert r.returncode == 0, r.stderr
    return path


@pytest.fixture
def server(recording):
    s = S.PageServer(recording, "127.0.0.1", free_port()).start()
    yield s
    s.close()


def get(port: int, target: str, headers: dict | None = None) -> tuple[int, bytes]:
    """(status, body) of one GET (``headers`` may replace Host)."""
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    try:
        c.request("GET", target, headers={"Host": f"127.0.0.1:{port}", **(headers or {})})
        r = c.getresponse()
        return r.status, r.read() if r.status != 101 else b""
    finally:
        c.close()


def upgrade(port: int, target: str, headers: dict | None = None) -> tuple[int, bytes]:
    """(status, body) of a WebSocket handshake; a refusal's body is all the client ever gets."""
    key = base64.b64encode(os.urandom(16)).decode()
    return get(port, target, {"Upgrade": "websocket", "Connection": "Upgrade", "Sec-WebSocket-Key": key,
                              "Sec-WebSocket-Version": "13", **(headers or {})})


def assert_refused(status_body: tuple[int, bytes], recording, status: int = 403) -> None:
    got, body = status_body
    assert got == status, (got, body)
    assert len(body) < 200 and recording.read_bytes()[:64] not in body


def ws_url(s: S.PageServer) -> str:
    return f"ws://127.0.0.1:{s.port}/ws?token={s.token}"


def raw_socket(port: int, token: str) -> socket.socket:
    """A WebSocket opened by hand: handshake sent, the 101 read (what follows is left in the socket)."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=30)
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(f"GET /ws?token={token} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                 f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode())
    head = b""
    while b"\r\n\r\n" not in head:
        head += sock.recv(1)
    assert head.startswith(b"HTTP/1.1 101"), head
    return sock


def read_to_eof(sock: socket.socket) -> None:
    """Read until the server closes (socket timeout: it never did)."""
    while sock.recv(1 << 16):
        pass


# ------------------------------------------------------------------------------------------- who may ask


def test_the_page_and_the_socket_want_the_token(server, recording):
    port, token = server.port, server.token
    assert get(port, f"/?token={token}")[0] == 200
    for target in ("/", "/?token=", f"/?token={token[:-1]}", f"/?token={token}x", "/?token=%C3%A9"):
        assert_refused(get(port, target), recording)
        assert_refused(upgrade(port, target.replace("/?", "/ws?")), recording)
    assert upgrade(port, f"/ws?token={token}")[0] == 101
    assert S.PageServer(recording, "127.0.0.1", free_port()).token != token  # one per launch


def test_a_foreign_origin_gets_no_recording(server, recording):
    """A page of another site, open in the same browser, holding the token even: 403 before any byte."""
    target = f"/ws?token={server.token}"
    for origin in ("https://evil.example", "null", f"http://evil.example:{server.port}", f"https://127.0.0.1:{server.port}",
                   f"http://127.0.0.1:{server.port + 1}", f"http://localhost:{server.port}"):
        assert_refused(upgrade(server.port, target, {"Origin": origin}), recording)
    ws = websocket.create_connection(ws_url(server), origin=f"http://127.0.0.1:{server.port}", timeout=30)
    assert ws.recv() == recording.read_bytes()  # the page's own origin
    ws.close()


def test_a_rebinding_host_is_refused(server, recording):
    """A DNS-rebinding page reaches 127.0.0.1 under its own name: its Host names that domain."""
    port, token = server.port, server.token
    for host in (f"evil.example:{port}", "evil.example", f"127.0.0.1:{port + 1}", f"192.168.1.2:{port}", ""):
        assert_refused(get(port, f"/?token={token}", {"Host": host}), recording)
        assert_refused(get(port, WASM, {"Host": host}), recording)
        assert_refused(upgrade(port, f"/ws?token={token}", {"Host": host, "Origin": f"http://{host}"}), recording)
    for host in (f"localhost:{port}", f"[::1]:{port}", f"127.0.0.1:{port}"):  # the loopback names
        assert get(port, f"/?token={token}", {"Host": host})[0] == 200


def test_host_names_by_bind_address():
    ok = S.host_allowed
    assert ok("127.0.0.1:9090", "127.0.0.1", 9090) and ok("LOCALHOST:9090", "127.0.0.1", 9090)
    assert not ok("127.0.0.1:9091", "127.0.0.1", 9090) and not ok(None, "127.0.0.1", 9090)
    assert not ok("10.0.0.5:9090", "127.0.0.1", 9090) and not ok("127.0.0.1:x", "127.0.0.1", 9090)
    # every interface: any address literal (a rebinding page has a name) and this machine's own name
    assert ok("10.0.0.5:9090", "0.0.0.0", 9090) and ok(f"{socket.gethostname()}:9090", "0.0.0.0", 9090)
    assert not ok("evil.example:9090", "0.0.0.0", 9090) and not ok("evil.example:9090", "::", 9090)
    assert ok("10.0.0.5:9090", "10.0.0.5", 9090) and not ok("localhost:9090", "10.0.0.5", 9090)


# --------------------------------------------------------------------------------------- what it takes


def test_an_oversized_or_binary_message_closes_its_socket_and_the_server_serves_on(server, recording):
    for message, opcode, code in (("x" * (S.MAX_MESSAGE + 1), websocket.ABNF.OPCODE_TEXT, 1009),
                                  (b"\0" * 10, websocket.ABNF.OPCODE_BINARY, 1003)):
        ws = websocket.create_connection(ws_url(server), timeout=30)
        assert ws.recv() == recording.read_bytes()
        ws.send(message, opcode)
        frame = ws.recv_frame()
        assert frame.opcode == websocket.ABNF.OPCODE_CLOSE and struct.unpack(">H", frame.data[:2])[0] == code
        ws.close()
    ws = websocket.create_connection(ws_url(server), timeout=30)
    assert ws.recv() == recording.read_bytes()
    ws.close()


def test_at_most_max_sockets_pages_at_once(server, recording):
    open_ = [websocket.create_connection(ws_url(server), timeout=30) for _ in range(S.MAX_SOCKETS)]
    assert_refused(upgrade(server.port, f"/ws?token={server.token}"), recording, 503)
    for ws in open_:
        ws.close()
    end = time.monotonic() + 30
    while server.sockets and time.monotonic() < end:  # the server sees the closes
        time.sleep(0.05)
    ws = websocket.create_connection(ws_url(server), timeout=30)
    assert ws.recv() == recording.read_bytes()
    ws.close()


def test_a_frame_announcing_2_63_bytes_closes_the_socket_and_prints_nothing(recording):
    """The process as users run it: a frame header announcing 2^63 or 2^64-1 bytes (the old server printed an
    OverflowError traceback) and a garbled request close their connection; nothing lands on stderr."""
    with WebServer(recording) as s:
        port, token = s.web_port, s.url.split("token=")[1]
        for n in (1 << 63, (1 << 64) - 1, 1 << 40):
            sock = raw_socket(port, token)
            sock.sendall(bytes([0x81, 0x80 | 127]) + struct.pack(">Q", n) + os.urandom(4) + b"x" * 100)
            read_to_eof(sock)
            sock.close()
        with socket.create_connection(("127.0.0.1", port), timeout=30) as sock:
            sock.sendall(b"\x16\x03\x01 not http at all\r\n\r\n")
            read_to_eof(sock)
        assert get(port, f"/?token={token}")[0] == 200
        os.kill(s.proc.pid, signal.SIGINT)
        s.proc.wait(timeout=60)
    assert "Traceback" not in s.stderr and "Error" not in s.stderr, s.stderr


# ------------------------------------------------------------------------------------------- resources


def test_idle_connections_take_no_thread(server, recording):
    """50 connections that send nothing, and 8 pages: no thread each; all closed, the count is back."""
    before = threading.active_count()
    idle = [socket.create_connection(("127.0.0.1", server.port), timeout=30) for _ in range(50)]
    pages = [websocket.create_connection(ws_url(server), timeout=30) for _ in range(S.MAX_SOCKETS)]
    for ws in pages:
        assert ws.recv() == recording.read_bytes()
    during = threading.active_count()
    for c in [*idle, *pages]:
        c.close()
    assert during <= before + S.CLICK_THREADS + 1, (before, during)
    end = time.monotonic() + 30
    while threading.active_count() > before + S.CLICK_THREADS and time.monotonic() < end:
        time.sleep(0.1)
    assert threading.active_count() <= before + S.CLICK_THREADS


def test_slow_viewer_downloads_share_the_file(server):
    """20 clients asking for the 65 MB wasm and reading nothing past its headers: the file is streamed from disk
    (the old server held a copy per client: +1.3 GB for 20)."""
    import psutil

    me = psutil.Process()
    size = (S.static_dir() / "re_viewer_bg.wasm").stat().st_size
    before = me.memory_info().rss
    slow = []
    for _ in range(20):
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        sock.settimeout(30)
        sock.connect(("127.0.0.1", server.port))
        sock.sendall(f"GET {WASM} HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\n\r\n".encode())
        assert sock.recv(12) == b"HTTP/1.1 200"  # serving it has begun
        slow.append(sock)
    grown = me.memory_info().rss - before
    for sock in slow:
        sock.close()
    assert grown < 3 * size, f"RSS grew {grown / 2**20:.0f} MiB for 20 slow downloads of {size / 2**20:.0f} MiB"
    assert get(server.port, WASM)[1].__len__() == size  # and it still serves the whole file


def test_the_events_kept_are_few_and_short(recording):
    app = S.ClickApp(recording)
    hello, answer = app.new_connection()
    assert hello == []  # a recording alone: no edit tools
    for i in range(S.KEEP_EVENTS * 3):
        assert answer('{"type": "nothing", "pad": "' + "x" * 100_000 + f'{i}"' + "}") == []
    assert len(app.events) == S.KEEP_EVENTS and all(len(e) <= S.KEEP_EVENT_CHARS for e in app.events)
