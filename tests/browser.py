"""Helpers for end-to-end tests of ``fviz open``: the CLI in a subprocess, the web viewer's server, and a
headless Chromium driven over the DevTools protocol.

Debian's chromium at /usr/bin/chromium (``.ci/install-browser``); missing: skip locally, fail when CI=true.
Software rendering so that WebGL works without a GPU: Mesa's llvmpipe where Chromium can use it (fviz's page
settles in ~12 s and ~20 s of CPU on an idle 2-core machine; with SwiftShader the GPU process alone took ~35 s),
else Chromium's own SwiftShader; ``FVIZ_BROWSER_GL=swiftshader`` forces the latter. Every process started here
runs in its own process group and is killed, with its group, by ``close()`` (use the context managers).
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from fviz.viewer import stop_group

CHROMIUM = Path(os.environ.get("FVIZ_CHROMIUM", "/usr/bin/chromium"))
WINDOW = (1600, 1000)
LLVMPIPE = ("--use-gl=angle", "--use-angle=gl-egl", "--ignore-gpu-blocklist")
SWIFTSHADER = ("--use-angle=swiftshader", "--enable-unsafe-swiftshader")
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-background-networking",
    "--no-first-run",
    "--disable-component-update",
    "--disable-sync",
    "--disable-quic",
    # Requests beyond the local servers (Rerun's web viewer fetches fonts, checks for releases and sends telemetry)
    # fail at once: every host but 127.0.0.1 is unknown, so that tests stay on the machine. (Not DevTools'
    # Network.setBlockedURLs: the Network domain sends every frame the page's WebSocket carries, the recording
    # included, to this process as an event.)
    "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1",
    f"--window-size={WINDOW[0]},{WINDOW[1]}",
)


# The CLI exactly as users run it (``fviz.cli:main``: FvizError -> one line on stderr, exit 2).
FVIZ = (sys.executable, "-c", "from fviz.cli import main; main()")


from cli_util import run_fviz  # noqa: E402,F401 (one runner for the suite: the fork server's)


def inspect_recording(kitti_root: Path, out: Path) -> tuple[Path, dict]:
    """``fviz inspect pair`` on KITTI odometry 00, temporal pair frames 3 -> 4: (recording, its --json)."""
    r = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal",
                 "--frame", "3", "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    return out, json.loads(r.stdout)


def eval_run(kitti_root: Path, out: Path, frames: str, estimators) -> Path:
    """``fviz eval`` on KITTI odometry 00, temporal pairs of ``frames``, one worker: the run folder."""
    r = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", frames,
                 *[a for e in estimators for a in ("-e", e)], "--workers", "1", "--no-progress", "--out-dir", out, timeout=600)
    assert r.returncode == 0, r.stderr
    return out


def in_ci() -> bool:
    return os.environ.get("CI", "").lower() == "true"


def require_chromium() -> Path:
    """The browser, or skip (locally) / fail (CI=true)."""
    if not (CHROMIUM.is_file() and os.access(CHROMIUM, os.X_OK)):
        msg = f"{CHROMIUM} missing (install it with .ci/install-browser)"
        if in_ci():
            pytest.fail(msg)
        pytest.skip(msg)
    return CHROMIUM


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_port(port: int, timeout: float, proc: subprocess.Popen | None = None) -> None:
    """Until something accepts TCP connections on 127.0.0.1:port (or the process dies: RuntimeError)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"process exited with {proc.returncode} before port {port} opened")
        with socket.socket() as s:
            s.settimeout(0.5)
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise TimeoutError(f"nothing listening on 127.0.0.1:{port} after {timeout:.0f} s")


def kill_group(proc: subprocess.Popen | None, timeout: float = 10) -> None:
    """Stop a process started with ``start_new_session=True`` and its whole group (None: nothing)."""
    if proc is not None:
        stop_group(proc, timeout)


def process_tree(pid: int) -> list:
    """psutil.Process of pid and all its descendants (those still alive)."""
    import psutil

    try:
        root = psutil.Process(pid)
        return [root, *root.children(recursive=True)]
    except psutil.NoSuchProcess:
        return []


def listening(procs: list) -> set[tuple[str, int]]:
    """(address, port) of every TCP socket in LISTEN state held by these processes."""
    import psutil

    out = set()
    for p in procs:
        try:
            conns = p.net_connections(kind="tcp")
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
        out |= {(c.laddr.ip, c.laddr.port) for c in conns if c.status == psutil.CONN_LISTEN}
    return out


class WebServer:
    """``fviz open FILE --web --web-port W [extra]`` on a free port (page and WebSocket), until ``close()``;
    ``command``: fviz's arguments in place of ``open FILE`` (``("inspect", "pair", ...)``: inspect's page, whose URL
    it prints once the pair is evaluated and recorded).

    url: the URL it printed (with its token); stderr: what it wrote there (after close)."""

    def __init__(self, recording: Path | None, *extra: str, timeout: float = 120, command=None):
        self.web_port = free_port()
        args = [str(a) for a in command] if command is not None else ["open", str(recording)]
        self.proc = subprocess.Popen(
            [*FVIZ, *args, "--web", "--web-port", str(self.web_port), *extra],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
        )
        self.lines: list[str] = []
        self.stderr = ""
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        try:
            end = time.monotonic() + timeout
            while not any("http://" in line for line in self.lines):
                if self.proc.poll() is not None or time.monotonic() > end:
                    raise RuntimeError(f"fviz {' '.join(args[:2])} --web printed no URL (exit {self.proc.poll()}): "
                                       f"{self.proc.stderr.read() if self.proc.poll() is not None else ''}")
                time.sleep(0.05)
            self.url = next(w for line in self.lines for w in line.split() if w.startswith("http://"))
            wait_port(self.web_port, timeout, self.proc)
        except BaseException:
            self.close()
            raise

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)

    def processes(self) -> list:
        return process_tree(self.proc.pid)

    def close(self) -> None:
        """SIGTERM to fviz alone (it must stop its server, which runs in a session of its own); whatever of
        its process tree is still alive 10 s later is listed in ``survivors``, then killed."""
        import psutil

        tree = self.processes()
        if self.proc.poll() is None:
            self.proc.terminate()
        _, alive = psutil.wait_procs(tree, timeout=10)
        self.survivors = [p.pid for p in alive]
        kill_group(self.proc)
        for p in alive:
            try:
                p.kill()
            except psutil.NoSuchProcess:
                pass
        if self.proc.stderr is not None:
            try:
                self.stderr = self.proc.stderr.read()
            except ValueError:
                pass

    def __enter__(self) -> "WebServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def decode_png(data: bytes) -> np.ndarray:
    """PNG bytes -> (H, W, 3) uint8 RGB."""
    import cv2

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError("not a PNG")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


_GL: dict[Path, tuple[str, ...]] = {}


def gl_flags(exe: Path) -> tuple[str, ...]:
    """The rendering flags for this Chromium: llvmpipe's where a page gets WebGL2 from it, else SwiftShader's
    (probed once per process)."""
    if os.environ.get("FVIZ_BROWSER_GL", "").lower() == "swiftshader":
        return SWIFTSHADER
    if exe not in _GL:
        with Chromium(exe=exe, gl=LLVMPIPE) as probe:
            _GL[exe] = LLVMPIPE if "llvmpipe" in (probe.webgl_renderer() or "") else SWIFTSHADER
    return _GL[exe]


class Chromium:
    """``with Chromium(url) as b: png = b.screenshot()``: one headless browser showing ``url``."""

    def __init__(self, url: str = "about:blank", exe: Path | None = None, startup_timeout: float = 30,
                 gl: tuple[str, ...] | None = None):
        import websocket  # websocket-client, in the test extra

        self.exe = exe or require_chromium()
        self.gl = gl if gl is not None else gl_flags(self.exe)
        self.port = free_port()
        self.profile = tempfile.mkdtemp(prefix="fviz-chromium-")
        self.log = open(Path(self.profile) / "chromium.log", "w+b")
        self.proc = subprocess.Popen(
            [str(self.exe), *FLAGS, *self.gl, f"--remote-debugging-port={self.port}", f"--user-data-dir={self.profile}", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True,
        )
        self.events: list[dict] = []
        self._id = 0
        try:
            wait_port(self.port, startup_timeout, self.proc)
            pages = []
            end = time.monotonic() + startup_timeout
            while not pages and time.monotonic() < end:
                with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/json/list", timeout=5) as r:
                    pages = [t for t in json.load(r) if t.get("type") == "page"]
                if not pages:
                    time.sleep(0.2)
            if not pages:
                raise RuntimeError("chromium opened no page")
            self.ws = websocket.create_connection(pages[0]["webSocketDebuggerUrl"], timeout=30, suppress_origin=True,
                                                  skip_utf8_validation=True)  # pure Python: ~20 s of CPU a screenshot
            self.call("Page.enable")
            self.call("Runtime.enable")
            # the viewport exactly WINDOW (the window size includes no browser chrome in headless, but be sure)
            self.call("Emulation.setDeviceMetricsOverride",
                      {"width": WINDOW[0], "height": WINDOW[1], "deviceScaleFactor": 1, "mobile": False})
            if url != "about:blank":
                self.navigate(url)
        except BaseException:
            self.close()
            raise

    def call(self, method: str, params: dict | None = None, timeout: float = 30) -> dict:
        """Send one DevTools command and return its result (events received meanwhile go to ``events``)."""
        self._id += 1
        msg_id = self._id
        self.ws.send(json.dumps({"id": msg_id, "method": method, "params": params or {}}))
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.ws.settimeout(max(0.1, end - time.monotonic()))
            msg = json.loads(self.ws.recv())
            if msg.get("id") == msg_id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})
            if "method" in msg:
                self.events.append(msg)
        raise TimeoutError(f"{method}: no answer in {timeout} s")

    def evaluate(self, expression: str, timeout: float = 120):
        """The value of a JavaScript expression in the page."""
        return self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True}, timeout)["result"].get("value")

    def click(self, at, hover: float = 1.5) -> float:
        """A left click at screen ``at``: the pointer moves there and rests ``hover`` s (a frame or two: the viewer
        picks what is under the pointer), then press and release back to back (Rerun's viewer takes a press and
        release further apart than 0.8 s of its clock for a drag; frames are slow in software). -> the time of the
        press (monotonic)."""
        x, y = map(float, at)
        self.call("Input.dispatchMouseEvent", {"type": "mouseMoved", "x": x, "y": y})
        time.sleep(hover)
        t = time.monotonic()
        for kind in ("mousePressed", "mouseReleased"):
            self.call("Input.dispatchMouseEvent", {"type": kind, "x": x, "y": y, "button": "left", "buttons": 1, "clickCount": 1})
        return t

    def webgl_renderer(self) -> str | None:
        """The renderer behind the page's WebGL2 (None: no WebGL2)."""
        return self.evaluate("(() => { const g = document.createElement('canvas').getContext('webgl2'); if (!g) return null;"
                             " const d = g.getExtension('WEBGL_debug_renderer_info');"
                             " return g.getParameter(d ? d.UNMASKED_RENDERER_WEBGL : g.RENDERER); })()")

    def navigate(self, url: str) -> None:
        self.call("Page.navigate", {"url": url})

    def screenshot(self, retries: int = 20, timeout: float = 90) -> bytes:
        """PNG of the viewport (retried while the page is between documents). The first frames of the
        viewer can take half a minute on two software-rendering cores: hence the long timeout."""
        for attempt in range(retries):
            try:
                return base64.b64decode(self.call("Page.captureScreenshot", {"format": "png"}, timeout)["data"])
            except RuntimeError as exc:
                if "Not attached" not in str(exc) or attempt == retries - 1:
                    raise
                time.sleep(0.25)
        raise AssertionError("unreachable")

    def log_tail(self, n: int = 15) -> str:
        """The last lines chromium wrote (for failure messages)."""
        self.log.flush()
        self.log.seek(0)
        return "\n".join(self.log.read().decode(errors="replace").splitlines()[-n:])

    def console_errors(self) -> list[str]:
        """Uncaught exceptions and console.error messages seen so far (for failure messages)."""
        out = []
        for e in self.events:
            if e["method"] == "Runtime.exceptionThrown":
                out.append(e["params"]["exceptionDetails"].get("text", "exception"))
            elif e["method"] == "Runtime.consoleAPICalled" and e["params"].get("type") == "error":
                out.append(" ".join(str(a.get("value", a.get("description", ""))) for a in e["params"].get("args", [])))
        return out

    def wait_stable(self, ready, timeout: float = 60, interval: float = 1.0, stable: int = 3,
                    tolerance: float = 0.25, shot_timeout: float = 90) -> tuple[bytes, np.ndarray, float, int]:
        """Poll screenshots until ``ready(rgb)`` holds and ``stable`` consecutive ones differ by less than
        ``tolerance`` (mean absolute grey-level difference), or until ``timeout`` s. A screenshot the browser
        takes longer than ``shot_timeout`` s to answer (a loaded machine) is asked for again, within ``timeout``.
        -> (png, rgb, seconds waited, screenshots taken); at the timeout the last one is returned."""
        t0 = time.monotonic()
        prev, calm, n = None, 0, 0
        png = rgb = None
        while True:
            try:
                png = self.screenshot(timeout=shot_timeout)
            except TimeoutError:
                if time.monotonic() - t0 > timeout:
                    raise
                continue
            rgb = decode_png(png)
            n += 1
            if prev is not None and prev.shape == rgb.shape and ready(rgb):
                diff = float(np.abs(rgb.astype(np.int16) - prev.astype(np.int16)).mean())
                calm = calm + 1 if diff < tolerance else 0
            else:
                calm = 0
            prev = rgb
            if calm >= stable or time.monotonic() - t0 > timeout:
                return png, rgb, time.monotonic() - t0, n
            time.sleep(interval)

    def close(self) -> None:
        ws = getattr(self, "ws", None)
        if ws is not None:
            try:
                ws.close()
            except Exception:
                pass
        kill_group(self.proc)
        self.log.close()
        shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self) -> "Chromium":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
