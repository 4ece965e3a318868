"""The viewer processes fviz starts: the web viewer's URL is printed only once it serves, never on a busy port;
its server dies with fviz (SIGTERM, SIGKILL), for ``open --web`` and ``inspect --web``; the native viewer
without a display is a one-line error. Real subprocesses, real signals, real sockets; conditions are polled
with a generous budget."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from cli_util import assert_one_line_error, run_fviz

from fviz.viewer import free_port, strip_ansi, web_command

BUDGET_S = 60.0


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("viewer") / "pair.rrd"
    r = run_fviz("inspect", "pair", "--synthetic", "--seed", "0", "-e", "8point", "--out", path)
    assert r.returncode == 0, r.stderr
    return path


def two_ports() -> tuple[int, int]:
    port, web_port = free_port(), free_port()
    while web_port == port:
        web_port = free_port()
    return port, web_port


def answers(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1):
            return True
    except OSError:
        return False


def alive(pid: int) -> bool:
    """Running (a zombie, dead but not yet reaped, counts as gone)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def poll(condition, what: str) -> None:
    end = time.monotonic() + BUDGET_S
    while not condition():
        assert time.monotonic() < end, f"{what} within {BUDGET_S} s"
        time.sleep(0.05)


def start_web(*args: str) -> tuple[subprocess.Popen, str]:
    """fviz serving a web viewer: the process and the URL it printed (the first stdout line with one)."""
    proc = subprocess.Popen([sys.executable, "-m", "fviz", *args], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    line = "-"
    while line and "http://" not in line:
        line = proc.stdout.readline()
    if "http://" not in line:
        proc.kill()
        raise AssertionError(f"no URL (exit {proc.wait()}): {line!r} {proc.stderr.read()}")
    return proc, next(w for w in line.split() if w.startswith("http://"))


def page_status(url: str) -> int:
    with urllib.request.urlopen(url, timeout=10) as r:
        return r.status


@pytest.fixture
def busy_port():
    """A port something else listens on (what another user's viewer would be)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield s.getsockname()[1]


# ------------------------------------------------------------------------------ the URL printed only once it serves


@pytest.mark.parametrize("mode, flag", [("--web", "--web-port"), ("--web-static", "--port"), ("--web-static", "--web-port")])
def test_busy_port_is_refused_before_any_url(recording, busy_port, mode, flag):
    """--port is Rerun's recording server (--web-static); --web serves page and WebSocket on --web-port alone."""
    port, web_port = two_ports()
    ports = {"--port": port, "--web-port": web_port, flag: busy_port}
    r = run_fviz("open", recording, mode, "--port", ports["--port"], "--web-port", ports["--web-port"], timeout=BUDGET_S)
    assert_one_line_error(r, 2, f"{flag} {busy_port}", "already in use")
    assert "http://" not in r.stdout


def test_inspect_web_takes_ports_and_refuses_a_busy_one_before_any_work(busy_port, tmp_path):
    out = tmp_path / "p.rrd"
    r = run_fviz("inspect", "pair", "--synthetic", "--seed", "0", "-e", "8point", "--out", out, "--web",
                 "--port", free_port(), "--web-port", busy_port, timeout=BUDGET_S * 2)
    assert_one_line_error(r, 2, f"--web-port {busy_port}: port {busy_port} on 127.0.0.1 is already in use")
    assert "http://" not in r.stdout and not out.exists()


@pytest.mark.parametrize("mode", ["--web", "--web-static"])
def test_url_is_printed_once_the_viewer_serves(recording, mode):
    port, web_port = two_ports()
    proc, url = start_web("open", str(recording), mode, "--port", str(port), "--web-port", str(web_port))
    try:
        assert url.startswith(f"http://127.0.0.1:{web_port}/")
        assert f"127.0.0.1:{port}" in url if mode == "--web-static" else "?token=" in url
        assert page_status(url) == 200  # no waiting: it already serves
        assert answers(port) == (mode == "--web-static")  # --web: page and WebSocket on --web-port alone
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            assert proc.wait(timeout=BUDGET_S) == 0
        finally:
            proc.kill()  # a no-op once it exited; else its viewer must not outlive the test (it dies with fviz)
    assert not answers(web_port) and not answers(port)


def test_rerun_errors_lose_their_ansi_escapes(recording, busy_port):
    """A real error of Rerun's server is coloured; what fviz shows of it is not. Its recording port taken: Rerun
    exits at once (its web port taken, Rerun 0.41 sometimes serves on regardless, so that is no error to wait for)."""
    cmd, _ = web_command(recording, "127.0.0.1", busy_port, free_port())
    raw = subprocess.run(cmd, capture_output=True, text=True, timeout=5 * BUDGET_S).stderr
    assert "\x1b[" in raw
    clean = strip_ansi(raw)
    assert "\x1b" not in clean and "already in use" in clean


# ------------------------------------------------------------------------------ the server dies with fviz


def _server_dies_with_fviz(args: list[str], sig: int, mode: str = "--web") -> None:
    """``--web``: fviz serves the page itself (threads, no child process); ``--web-static``: Rerun's server, a
    child. Either way nothing serves once fviz is gone."""
    port, web_port = two_ports()
    proc, _ = start_web(*args, mode, "--port", str(port), "--web-port", str(web_port))
    servers = children(proc.pid)
    if mode == "--web-static":
        assert servers and all(alive(pid) for pid in servers)
    assert answers(web_port) and answers(port) == (mode == "--web-static")
    os.kill(proc.pid, sig)
    proc.wait(timeout=BUDGET_S)
    try:
        poll(lambda: not any(alive(pid) for pid in servers), "the viewer's server stops")
        poll(lambda: not answers(port) and not answers(web_port), "its ports close")
    finally:
        for pid in servers:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize("mode", ["--web", "--web-static"])
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL, signal.SIGHUP])
def test_open_web_server_dies_with_fviz(recording, sig, mode):
    _server_dies_with_fviz(["open", str(recording)], sig, mode)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_inspect_web_server_dies_with_fviz(tmp_path, sig):
    _server_dies_with_fviz(["inspect", "pair", "--synthetic", "--seed", "0", "-e", "8point", "--out",
                            str(tmp_path / "p.rrd")], sig)


# ------------------------------------------------------------------------------ no display


def _no_display() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a display is an X11/Wayland matter")
def test_native_viewer_without_display_says_so(recording):
    r = subprocess.run([sys.executable, "-m", "fviz", "open", str(recording)], capture_output=True, text=True,
                       env=_no_display(), timeout=BUDGET_S)
    assert_one_line_error(r, 2, "no display", f"fviz open {recording} --web")
    assert "started" not in r.stdout


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a display is an X11/Wayland matter")
def test_inspect_spawn_without_display_says_so_before_any_work(tmp_path):
    out = tmp_path / "p.rrd"
    r = subprocess.run([sys.executable, "-m", "fviz", "inspect", "pair", "--synthetic", "--seed", "0", "-e", "8point",
                        "--out", str(out), "--spawn"], capture_output=True, text=True, env=_no_display(), timeout=BUDGET_S * 2)
    assert_one_line_error(r, 2, "--spawn: no display", "--web")
    assert not out.exists()
