"""Open recordings in Rerun's viewers. Servers bind 127.0.0.1 unless the user asks otherwise (Rerun's own
default is 0.0.0.0), on ports checked free first (Rerun would otherwise stream into whatever viewer already
listens there), and live no longer than fviz: the ``rerun`` binary runs as fviz's own child with
``PR_SET_PDEATHSIG`` (Linux), in a process group fviz stops on Ctrl-C, SIGTERM and SIGHUP.
"""

from __future__ import annotations

import errno
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from fviz.errors import FvizError

# Seconds the web viewer may take to serve its page (a loaded 2-core machine takes 1-3).
START_TIMEOUT_S = 60.0
_ANSI = re.compile(r"\x1b\[[0-9;?]*[ -/]*[@-~]")

# Run as ``python -c PARENT_DEATH PPID EXE ARGS...``: ask the kernel for SIGTERM when the parent dies,
# then become the ``rerun`` binary (the request survives exec). Without prctl (not Linux) it only execs.
PARENT_DEATH = """import os, signal, sys
try:
    import ctypes
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
except (OSError, AttributeError):
    pass
if os.getppid() != int(sys.argv[1]):
    sys.exit(1)  # the parent died before prctl took effect
os.execv(sys.argv[2], sys.argv[2:])
"""


def _rerun_cmd() -> list[str]:
    """The ``rerun`` binary itself: the ``rerun`` script on PATH is a Python wrapper that runs it as a
    child, out of reach of the signals and the parent-death request meant for the server."""
    import importlib.util

    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin:
        exe = Path(spec.origin).with_name("rerun")
        if os.access(exe, os.X_OK):
            return [str(exe)]
    exe = shutil.which("rerun")
    return [exe] if exe else [sys.executable, "-m", "rerun"]


def _tied_to_fviz(cmd: list[str]) -> list[str]:
    """``cmd`` started so that it receives SIGTERM when this process dies (even by SIGKILL)."""
    exe = cmd[0] if os.path.isabs(cmd[0]) else shutil.which(cmd[0]) or cmd[0]
    return [sys.executable, "-c", PARENT_DEATH, str(os.getpid()), exe, *cmd[1:]]


def strip_ansi(text: str) -> str:
    return _ANSI.sub("", text)


def free_port(host: str = "127.0.0.1") -> int:
    """A port nothing listens on now (the OS's pick)."""
    with socket.socket(_family(host), socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _family(host: str) -> socket.AddressFamily:
    return socket.AF_INET6 if ":" in host else socket.AF_INET


def _answers(host: str, port: int) -> bool:
    """Whether something accepts TCP connections on host:port."""
    shown = "127.0.0.1" if host in ("0.0.0.0", "") else "::1" if host == "::" else host
    try:
        with socket.create_connection((shown, port), timeout=1):
            return True
    except OSError:
        return False


def check_port_free(host: str, port: int, flag: str) -> None:
    """FvizError naming ``flag`` when host:port is taken (a listener there, or the address in use)."""
    busy = _answers(host, port)
    if not busy:
        with socket.socket(_family(host), socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind((host, port))
            except OSError as exc:
                if exc.errno != errno.EADDRINUSE:
                    raise FvizError(f"{flag} {port}: cannot listen on {host} ({exc.strerror})") from None
                busy = True
    if busy:
        raise FvizError(f"{flag} {port}: port {port} on {host} is already in use (another viewer?); choose another "
                        f"{flag}")


def has_display() -> bool:
    """Whether a native window can open: on Linux an X11 or Wayland display must be named."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def native_command(path: Path, port: int, blueprint: Path | None = None) -> list[str]:
    """The native viewer on ``path`` (and a blueprint .rbl that replaces the stored one), its own viewer
    server on 127.0.0.1:``port``."""
    return [*_rerun_cmd(), "--bind", "127.0.0.1", "--port", str(port), str(path), *([str(blueprint)] if blueprint else [])]


def spawn_native(path: Path, blueprint: Path | None = None) -> subprocess.Popen:
    """Start the native viewer on a file and return at once: on 127.0.0.1, on a port picked free now (on
    Rerun's default port it would stream the file into any viewer already listening there)."""
    if not has_display():
        raise FvizError(f"no display for the native viewer (DISPLAY and WAYLAND_DISPLAY are unset): "
                        f"serve it in the browser with: fviz open {path} --web")
    return subprocess.Popen(native_command(Path(path), free_port(), blueprint), stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


def web_command(path: Path, host: str = "127.0.0.1", port: int = 9876, web_port: int = 9090,
                blueprint: Path | None = None) -> tuple[list[str], str]:
    """The command serving ``path`` (and a blueprint .rbl that replaces the stored one) in the web viewer,
    and the URL to open."""
    files = [str(path)] + ([str(blueprint)] if blueprint else [])
    cmd = [*_rerun_cmd(), *files, "--serve-web", "--bind", host, "--port", str(port), "--web-viewer-port", str(web_port)]
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    url = f"http://{shown}:{web_port}/?url=rerun%2Bhttp://{shown}:{port}/proxy"
    return cmd, url


def stop_group(proc: subprocess.Popen, timeout: float = 10) -> None:
    """Stop the process group of ``proc`` (started with ``start_new_session=True``): SIGTERM, SIGKILL if
    it lingers, and SIGKILL to any member that outlives the leader."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        try:
            proc.wait(timeout=timeout)
            os.killpg(proc.pid, signal.SIGKILL)  # the leader is gone: no member of its group survives it
        except subprocess.TimeoutExpired:
            continue
        except ProcessLookupError:
            pass
        break
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        pass


def _serving(host: str, port: int, web_port: int) -> bool:
    """Both servers accept connections and the web viewer's page loads."""
    import urllib.request

    if not (_answers(host, port) and _answers(host, web_port)):
        return False
    shown = "127.0.0.1" if host in ("0.0.0.0", "") else "[::1]" if host == "::" else f"[{host}]" if ":" in host else host
    try:
        with urllib.request.urlopen(f"http://{shown}:{web_port}/", timeout=5) as r:
            return r.status == 200
    except OSError:
        return False


def _last_line(lines: list[str]) -> str:
    text = [strip_ansi(line).strip() for line in lines if strip_ansi(line).strip()]
    return text[-1] if text else "no message"


def prepare_serving(path: Path, host: str, port: int | None, web_port: int) -> None:
    """What every web server of fviz checks first (the recording, its free ports: ``port`` is Rerun's recording
    server of ``--web-static``, None for fviz's page, which serves on ``web_port`` alone), and SIGTERM / SIGHUP
    turned into Ctrl-C, so that the server stops the same way on each."""
    if not Path(path).is_file():
        raise FvizError(f"no such recording: {path}")
    if port is not None:
        if port == web_port:
            raise FvizError(f"--port and --web-port are both {port}: they need two ports")
        check_port_free(host, port, "--port")
    check_port_free(host, web_port, "--web-port")

    def _stop(signum, frame):
        raise KeyboardInterrupt

    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _stop)


def serve_web(path: Path, host: str = "127.0.0.1", port: int = 9876, web_port: int = 9090,
              blueprint: Path | None = None) -> None:
    """Serve Rerun's web viewer (``--web-static``) until Ctrl-C, SIGTERM or SIGHUP; print its URL once it serves."""
    prepare_serving(path, host, port, web_port)
    cmd, url = web_command(Path(path), host, port, web_port, blueprint)
    # Own process group, stopped as a whole; and killed by the kernel if fviz dies without stopping it.
    proc = subprocess.Popen(_tied_to_fviz(cmd), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, errors="replace", start_new_session=True)
    err: list[str] = []
    reader = threading.Thread(target=lambda: err.extend(proc.stderr), daemon=True)
    reader.start()
    try:
        end = time.monotonic() + START_TIMEOUT_S
        while proc.poll() is None and not _serving(host, port, web_port):
            if time.monotonic() > end:
                stop_group(proc)
                raise FvizError(f"the web viewer did not serve {url} within {START_TIMEOUT_S:.0f} s")
            time.sleep(0.1)
        if proc.poll() is None:
            print(f"web viewer: {url}  (Ctrl-C to stop)", flush=True)
            proc.wait()
    except KeyboardInterrupt:
        stop_group(proc)
        return
    reader.join(timeout=5)
    raise FvizError(f"the web viewer stopped (exit {proc.returncode}): {_last_line(err)}")
