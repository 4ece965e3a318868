"""train.rrd's watched pair clicked in a real browser: ``fviz open train.rrd --web`` on two synthetic pairs logged with
``fviz.log_training_step`` (a noisy network and the pairs' mean F as the baseline, at two steps); headless Chromium
loads the page, which opens on the first watched pair's tab; a click on a plain pixel of its image a (CDP mouse
events, far from the fixed correspondences and their static lines) must draw, in image b, that point's epipolar line
under the network (orange) and the baseline (cyan) where OpenCV's ``computeCorrespondEpilines`` puts them: Rerun
reports the click in the frame of the view (origin ``watch/{k}``), which fviz places as it places a pair's. Asserted on
the screenshots' pixels (saved under the test's tmp dir). Missing /usr/bin/chromium skips locally, fails when CI=true.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest
import rerun as rr
from browser import Chromium, WebServer
from test_interactive_web import click_answered, line_pixels, open_page, shot
from test_web_viewer import budget

import fviz
from fviz import api
from fviz.geometry import epipoles
from fviz.record import layout as L

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def train_rrd(tmp_path_factory):
    pairs = [fviz.synthetic_pair(seed=s, kind="temporal") for s in range(2)]
    true = np.stack([p.F_gt / np.linalg.norm(p.F_gt) for p in pairs])
    net = true * (1 + 0.2 * np.random.default_rng(1).normal(size=(2, 3, 3)))
    path = tmp_path_factory.mktemp("trainweb") / "train.rrd"
    rec = rr.RecordingStream("fviz-train")
    rec.save(str(path))
    for step in (0, 10):  # the same F's at both: whichever step the time cursor shows
        fviz.log_training_step(rec, step, pairs, net, names=["left", "right"], F_baseline=true.mean(0), baseline_name="mean F")
    rec.flush()
    rec.disconnect()
    return path, pairs[0], {"network": net[0], "mean F": true.mean(0)}


def test_a_click_on_a_watched_image_draws_the_network_and_baseline_lines(train_rrd, tmp_path):
    path, pair, Fs = train_rrd
    colors = {"network": L.watch_colors()[L.NET], "mean F": L.watch_colors()[L.BASELINE]}
    x_a, _ = api.watch_points(pair)
    w, h = pair.size_a
    grid = np.stack(np.meshgrid(np.arange(60, w - 60, 20.0), np.arange(40, h - 40, 20.0)), -1).reshape(-1, 2)
    p = grid[np.argmax([np.linalg.norm(x_a - q, axis=1).min() for q in grid])]  # a plain pixel, far from every one
    lines = {n: cv2.computeCorrespondEpilines(p.reshape(1, 1, 2).astype(np.float32), 1, F).reshape(3) for n, F in Fs.items()}

    def drawn(rgb, page):
        return {n: line_pixels(rgb, page, "b", lines[n], colors[n], pair.size_b, epipole=epipoles(Fs[n])[1]) for n in Fs}

    frame_a = cv2.cvtColor(pair.image_a, cv2.COLOR_RGB2GRAY) if pair.image_a.ndim == 3 else pair.image_a
    with WebServer(path) as server, Chromium(server.url) as b:
        assert "click a point of a watched pair" in "".join(server.lines)
        page = open_page(b, path, frame_a)
        before = shot(b)
        cv2.imwrite(str(tmp_path / "0-before.png"), cv2.cvtColor(before, cv2.COLOR_RGB2BGR))
        was = drawn(before, page)
        click_answered(b, page.screen("a", p))
        end = time.monotonic() + budget()
        while True:
            after = shot(b)
            now = drawn(after, page)
            shown = [n for n in Fs if now[n] - was[n] >= 15]
            if len(shown) == len(Fs) or time.monotonic() > end:
                break
            time.sleep(1)
        cv2.imwrite(str(tmp_path / "1-clicked.png"), cv2.cvtColor(after, cv2.COLOR_RGB2BGR))
        assert len(shown) == len(Fs), f"colours along their lines in image b, before -> after the click: {was} -> {now} ({tmp_path})"
