"""Click -> lines drawn (issue 27 §2): target 150 ms on a 2-core CPU, KITTI pair, 5 estimators and the truth.

    python benchmarks/bench_click.py [--clicks 50] [--browser]

- event received -> data logged: the JSON of a viewer's SelectionChangeEvent in, the bytes of the click's
  entities out (what ``fviz open --web`` sends to the page; encoded and flushed), median and p90 over clicks
  on keypoints and on plain pixels of either image; the same for the notebook path (``fviz.notebook.show``:
  handle -> logged and flushed to the widget);
- ``--browser``: headless Chromium on ``fviz open FILE --web``: click (CDP mouse events) -> the rrd bytes
  reach the page (the page's own clock) and -> the screenshot's pixels in image b change (polled screenshots:
  on software rendering a screenshot itself takes a large part of that).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from common import KITTI_ROOT, PROJECT

ESTIMATORS = ("8point", "ransac", "magsac", "lmeds", "7point")


def record(out: Path) -> Path:
    cmd = [sys.executable, "-m", "fviz", "inspect", "pair", "--kitti-root", str(KITTI_ROOT), "--sequence", "00",
           "--pair", "temporal", "--frame", "3", *[a for e in ESTIMATORS for a in ("-e", e)], "--out", str(out)]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, cwd=PROJECT)
    return out


def selection(position, path="/a/image", instance=None) -> str:
    item = {"type": "entity", "entity_path": path, "position": [float(position[0]), float(position[1]), 0.0]}
    if instance is not None:
        item["instance_id"] = int(instance)
    return json.dumps({"type": "selection_change", "application_id": "fviz-inspect", "recording_id": "r", "items": [item]})


def positions(fs, n: int, seed: int = 0) -> list:
    """Half keypoints (of a and of b, in the root frame), half plain pixels of either image."""
    from fviz.record.placement import offset_b

    rng = np.random.default_rng(seed)
    off = offset_b(fs.size_a)
    out = []
    for k in range(n):
        j = int(rng.integers(len(fs.x_a)))
        if k % 4 == 0:
            out.append(fs.x_a[j])
        elif k % 4 == 1:
            out.append(fs.x_b[j] + off)
        elif k % 4 == 2:
            out.append(rng.uniform([0, 0], fs.size_a))
        else:
            out.append(rng.uniform([0, 0], fs.size_b) + off)
    return out


def stats(name: str, seconds: list[float]) -> None:
    ms = np.array(seconds) * 1e3
    print(f"{name}: median {np.median(ms):.1f} ms, p90 {np.percentile(ms, 90):.1f} ms, max {ms.max():.1f} ms "
          f"over {len(ms)} clicks (target 150 ms)")


def bench_server(path: Path, n: int) -> None:
    from fviz.web.server import ClickApp

    app = ClickApp(path)
    _, answer = app.new_connection()
    fs = next(iter(app.pairs.values()))
    for p in positions(fs, n):
        assert answer(selection(p))
    stats("open --web: event received -> bytes of the click logged", app.timings)


def bench_notebook(n: int) -> None:
    from fviz.data.kitti import open_dataset
    from fviz.estimators.registry import get_estimator
    from fviz.evaluate import evaluate_pair

    import fviz.notebook

    pair = open_dataset(KITTI_ROOT, sequence="00").pair(3, "temporal")
    result = evaluate_pair(pair, [(e, get_estimator(e)) for e in ESTIMATORS])
    v = fviz.notebook.show(pair, result)
    times = []
    for p in positions(v.session.pairs[0], n):
        t0 = time.perf_counter()
        assert v.handle(selection(p)) is not None
        times.append(time.perf_counter() - t0)
    stats("notebook: event received -> logged and flushed to the widget", times)


def bench_browser(path: Path, clicks: int) -> None:
    sys.path.insert(0, str(PROJECT / "tests"))
    from browser import Chromium, WebServer
    from test_interactive_web import click_answered, click_keypoint, open_page

    from fviz.record.rebuild import click_pairs

    fs = click_pairs(path)[0]
    with WebServer(path) as server, Chromium(server.url) as b:
        page = open_page(b, path)
        page_ms, pixel_ms = [], []
        for k in range(clicks):
            click_answered(b, page.screen("b", (1200.0, 30.0)))  # a pixel of b (sky): b's lines go
            r = click_keypoint(b, page, 40 + 97 * k, fs)
            page_ms.append(r["page_ms"])
            pixel_ms.append(r["pixels_ms"])
        print(f"browser: click -> bytes at the page: median {statistics.median(page_ms):.0f} ms; click -> pixels "
              f"changed (screenshots polled): median {statistics.median(pixel_ms):.0f} ms over {clicks} clicks")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--clicks", type=int, default=50)
    ap.add_argument("--browser", action="store_true")
    ap.add_argument("--browser-clicks", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        path = record(Path(d) / "pair.rrd")
        bench_server(path, args.clicks)
        bench_notebook(args.clicks)
        if args.browser:
            bench_browser(path, args.browser_clicks)


if __name__ == "__main__":
    main()
