"""fviz's ``--web`` page: how long the viewer takes to start and settle, and its CPU, against a baseline measured
in the same run: the same page with the viewer's debug console lines let through (what fviz's page drops; ~15,000
lines from wgpu's shader compiler).

    python benchmarks/bench_page.py [--loads 2]

Headless Chromium (tests/browser.py: llvmpipe where it can, else SwiftShader) on ``fviz open FILE --web``, FILE
a synthetic pair inspected with two estimators, with DevTools' console listener on (an open DevTools console,
and the browser tests, which collect the page's errors) and off (a user's browser). Per load: seconds until the
screenshot shows the viewer and stays still (three screenshots in a row), and the CPU of Chromium's processes
(browser, page, GPU) to that point.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import PROJECT

sys.path.insert(0, str(PROJECT / "tests"))

# Run before the page's own scripts: console.debug counts its lines; not writable (the baseline), the page's own
# ``console.debug = () => {}`` fails silently and every line reaches the console.
COUNT_DEBUG = ("window.__debug_lines = 0; const debug = console.debug.bind(console);"
               "Object.defineProperty(console, 'debug', {value: (...a) => { window.__debug_lines++; debug(...a); },"
               " writable: WRITABLE, configurable: true});")


def chromium_cpu(pid: int) -> float:
    """CPU seconds of a Chromium and every process below it."""
    import psutil
    from browser import process_tree

    def cpu(p) -> float:
        try:
            t = p.cpu_times()
        except psutil.NoSuchProcess:  # a helper process that ended meanwhile
            return 0.0
        return t.user + t.system

    return sum(map(cpu, process_tree(pid)))


def load(recording: Path, keep_debug: bool, listener: bool) -> tuple[float, float, int]:
    """One page load -> (seconds to settle, Chromium's CPU seconds, debug lines that reached the console).
    ``listener``: DevTools' Runtime domain on (every console line is sent to this process)."""
    from browser import Chromium, WebServer
    from test_web_viewer import viewer_rendered

    with WebServer(recording) as server, Chromium() as b:
        if not listener:
            b.call("Runtime.disable")
        b.call("Page.addScriptToEvaluateOnNewDocument",
               {"source": COUNT_DEBUG.replace("WRITABLE", "false" if keep_debug else "true")})
        t0 = time.monotonic()
        b.navigate(server.url)
        b.wait_stable(viewer_rendered, timeout=300)
        seconds = time.monotonic() - t0
        return seconds, chromium_cpu(b.proc.pid), b.evaluate("window.__debug_lines")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loads", type=int, default=2, help="page loads of each kind (interleaved)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        recording = Path(tmp) / "pair.rrd"
        subprocess.run([sys.executable, "-m", "fviz", "inspect", "pair", "--synthetic", "--seed", "0", "-e", "8point",
                        "-e", "ransac", "--out", str(recording)], check=True, stdout=subprocess.DEVNULL, cwd=PROJECT)
        runs: dict[tuple[bool, bool], list] = {}
        for _ in range(args.loads):
            for listener in (True, False):
                for keep_debug in (False, True):
                    runs.setdefault((listener, keep_debug), []).append(load(recording, keep_debug, listener))
    med = {k: [statistics.median(col) for col in zip(*v)] for k, v in runs.items()}
    for (listener, keep_debug), (seconds, cpu, lines) in med.items():
        name = f"console listener {'on ' if listener else 'off'}, {'baseline (debug kept)' if keep_debug else 'fviz page'}"
        print(f"{name:48s} settled after {seconds:5.1f} s, Chromium CPU {cpu:5.1f} s, {lines:6.0f} debug lines "
              f"(median of {args.loads})")
    for listener in (True, False):
        (s0, c0, _), (s1, c1, _) = med[listener, False], med[listener, True]
        print(f"console listener {'on ' if listener else 'off'}: fviz page / baseline: time {s0 / s1:.2f}, CPU {c0 / c1:.2f}")


if __name__ == "__main__":
    main()
