"""From a run's plot to its pair, in a real browser (issue 42, item 2): ``fviz open RUN/eval.rrd --web`` on a run
without --full; a right-click in a metric's plot (Rerun 0.41 moves the time cursor there: a ``time_update`` on the
``pair`` timeline) makes fviz read that pair from the run and draw it: its image a shows on the screen, and a click
on one of its keypoints is answered (the page receives the click's bytes). ``fviz open RUN/compare.rrd --web``: a
left click on a pair's point of the chart draws that pair below it and moves the time cursor there."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from browser import Chromium, WebServer, eval_run
from test_interactive_web import Page, click_answered, open_page, shot, wait_received
from test_web_viewer import budget, find_image, to_gray, viewer_rendered

import fviz

pytestmark = [pytest.mark.browser, pytest.mark.kitti, pytest.mark.slow]


def right_click(b: Chromium, at) -> None:
    """A right click at screen ``at`` (Rerun's time series view: move the time cursor there)."""
    x, y = map(float, at)
    b.call("Input.dispatchMouseEvent", {"type": "mouseMoved", "x": x, "y": y})
    time.sleep(1.5)
    for kind in ("mousePressed", "mouseReleased"):
        b.call("Input.dispatchMouseEvent", {"type": kind, "x": x, "y": y, "button": "right", "buttons": 2, "clickCount": 1})


def test_a_right_click_in_a_plot_of_eval_rrd_draws_that_pair_clickable(kitti_root, tmp_path):
    run = eval_run(kitti_root, tmp_path / "run", "0:4", ("8point", "magsac"))
    with WebServer(run / "eval.rrd") as server, Chromium(server.url) as b:
        end = time.monotonic() + budget()
        while not (b.evaluate("window.fviz && window.fviz.received") or 0) >= 1:
            assert time.monotonic() < end, f"the page got no recording: {b.console_errors()[:3]}"
            time.sleep(1)
        b.wait_stable(viewer_rendered, timeout=budget())
        # the metrics tab opens first: the median SED's plot at the top left; its x axis spans pairs 0..2
        for at in ((230, 300), (120, 300)):
            right_click(b, at)
            if wait_received(b, 2, budget() / 2):
                break
        moves = [json.loads(e) for e in b.evaluate("window.fviz.events") if '"time_update"' in e]
        assert wait_received(b, 2, 1) and len(moves) >= 2, f"no pair drawn; the viewer's events: {moves}"
        index = int(moves[-1]["time"])
        pair, result = fviz.read_pair(run, index)
        page = open_page(b, None, pair.image_a)  # the drawn pair's image a, found on the screen
        j = int(np.argmin(np.linalg.norm(result.matches.x_a - [180.0, 200.0], axis=1)))
        click_answered(b, page.screen("a", result.matches.x_a[j]))
        rgb = shot(b)
        score, _, _ = find_image(to_gray(rgb), pair.image_a)
        assert score > 0.5, f"pair {index}'s image a left the screen after the click (score {score:.2f})"


def test_a_click_on_a_point_of_compare_rrd_draws_that_pair_clickable_and_moves_there(tmp_path):
    """``fviz open RUN/compare.rrd --web``: a left click on a pair's point of the chart draws that pair below the chart
    (its image a on the screen) and moves the viewer's time cursor to it (the page's time_ctrl: the viewer reports
    the pair's index); a click on one of its keypoints is answered."""
    from test_web_viewer import blobs

    from fviz.record import layout as L

    run = fviz.evaluate_run(fviz.select(seeds=(0, 3)), tmp_path / "run", estimators=("8point", "magsac"),
                            max_keypoints=200, workers=1)
    rrd = fviz.compare_runs(run, estimators=("8point", "magsac")).recording
    color = L.estimator_colors(["8point", "magsac"])["magsac"]
    with WebServer(rrd) as server, Chromium(server.url) as b:
        end = time.monotonic() + budget()
        while not (b.evaluate("window.fviz && window.fviz.received") or 0) >= 1:
            assert time.monotonic() < end, f"the page got no recording: {b.console_errors()[:3]}"
            time.sleep(1)
        b.wait_stable(viewer_rendered, timeout=budget())
        rgb = shot(b)
        top, width = 60, int(0.7 * rgb.shape[1])  # the chart: below Rerun's top bar (its orange warning), left of compare.md
        dots = [(x, y + top) for x, y, n in blobs(rgb, (0, top, width, rgb.shape[0] - top), color) if n <= 150]  # no legend bar
        assert len(dots) == 3, f"not the chart's three points of magsac's colour: {dots}"
        click_answered(b, dots[1])  # pair #1
        end = time.monotonic() + budget()
        while not b.evaluate("window.fviz.goto"):
            assert time.monotonic() < end, f"no pair picked; the viewer's events: {b.evaluate('window.fviz.events')[-5:]}"
            time.sleep(0.5)
        index = b.evaluate("window.fviz.goto.sequence")
        assert index == 1, index
        moved = lambda: any(json.loads(e).get("time") == index and json.loads(e)["type"] in ("time_update", "timeline_change")
                            for e in b.evaluate("window.fviz.events"))
        while not moved():
            assert time.monotonic() < end, f"the time cursor did not move to pair {index}: {b.evaluate('window.fviz.events')[-5:]}"
            time.sleep(0.5)
        pair, result = fviz.read_pair(run, index)
        b.wait_stable(viewer_rendered, timeout=budget())
        score, scale, (x, y, _, _) = find_image(to_gray(shot(b)), pair.image_a)  # the drawn pair's image a, on the screen
        assert score > 0.4, f"pair {index}'s image a not found below the chart (score {score:.2f})"  # crossed by white lines
        page = Page(x, y, scale, pair.size_a)
        j = int(np.argmin(np.linalg.norm(result.matches.x_a - np.array(pair.size_a) / 2, axis=1)))
        click_answered(b, page.screen("a", result.matches.x_a[j]))
        assert b.evaluate("window.fviz.message") is None, b.evaluate("window.fviz.message")  # no error
