"""End to end in a real browser: ``fviz open FILE --web`` serves a KITTI recording; headless Chromium
(software WebGL) loads the printed URL; screenshots are polled over the DevTools protocol until the viewer
has rendered and stopped changing; then the picture is checked: not blank, both KITTI frames found where the
stored blueprint puts them (image a left, image b right, top row), the coloured overlays drawn on them,
and the plot/summary row below. The screenshot is saved under the test's tmp dir (path printed).

Missing /usr/bin/chromium skips locally and fails when CI=true (``.ci/install-browser`` installs it).
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from browser import Chromium, WebServer, inspect_recording, require_chromium

pytestmark = [pytest.mark.browser, pytest.mark.kitti, pytest.mark.slow]

# Seconds for the viewer to load and settle: ~40 s on two software-rendering cores.
TIMEOUT = float(os.environ.get("FVIZ_BROWSER_TIMEOUT", "120"))
FRAMES = (3, 4)  # the pair inspected: odometry 00, temporal, frames 3 -> 4, camera 0


def distinct_colors(rgb: np.ndarray, step: int = 16) -> int:
    q = (rgb // step).astype(np.int32)
    return len(np.unique(q[..., 0] * 65536 + q[..., 1] * 256 + q[..., 2]))


def viewer_rendered(rgb: np.ndarray) -> bool:
    """The viewer's panels are drawn: Rerun's loading screen has < 150 distinct colours, the viewer > 1000."""
    return distinct_colors(rgb) > 400 and float(rgb.std()) > 25


def find_image(gray: np.ndarray, image: np.ndarray, scales=np.arange(0.30, 1.001, 0.01)) -> tuple[float, float, tuple[int, int, int, int]]:
    """Where ``image`` (H, W) appears in ``gray`` at any scale: (normalized correlation, scale, (x, y, w, h)).
    Matched at half resolution (fast); coordinates are full resolution."""
    import cv2

    g = cv2.resize(gray, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    best = (-1.0, 0.0, (0, 0, 0, 0))
    for s in scales:
        tpl = cv2.resize(image, None, fx=s / 2, fy=s / 2, interpolation=cv2.INTER_AREA)
        if tpl.shape[0] > g.shape[0] or tpl.shape[1] > g.shape[1] or min(tpl.shape) < 8:
            continue
        _, score, _, (x, y) = cv2.minMaxLoc(cv2.matchTemplate(g, tpl, cv2.TM_CCOEFF_NORMED))
        if score > best[0]:
            best = (float(score), float(s), (2 * x, 2 * y, 2 * tpl.shape[1], 2 * tpl.shape[0]))
    return best


def to_gray(img: np.ndarray) -> np.ndarray:
    import cv2

    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)


@pytest.fixture(scope="module")
def recording(kitti_root, tmp_path_factory):
    return inspect_recording(kitti_root, tmp_path_factory.mktemp("web") / "pair.rrd")[0]


def test_web_viewer_renders_the_recording(recording, odometry, tmp_path):
    require_chromium()
    pair = odometry.pair(FRAMES[0], "temporal")
    frames = {"a": to_gray(pair.image_a), "b": to_gray(pair.image_b)}
    shot_path = tmp_path / "web_viewer.png"
    server = browser = None
    try:
        server = WebServer(recording)
        browser = Chromium(server.url)
        png, rgb, seconds, n = browser.wait_stable(viewer_rendered, timeout=TIMEOUT)
        shot_path.write_bytes(png)
        print(f"\nscreenshot: {shot_path} ({rgb.shape[1]}x{rgb.shape[0]}, settled after {seconds:.1f} s, {n} shots)")
        context = (f"screenshot {shot_path}; console errors: {browser.console_errors()[-3:]}; "
                   f"chromium log:\n{browser.log_tail()}")
        assert seconds <= TIMEOUT, f"viewer did not settle in {TIMEOUT:.0f} s; {context}"
        # 1. the viewer rendered: a busy picture, not the loading screen nor a blank page
        assert rgb.shape[:2] == (1000, 1600), rgb.shape
        assert viewer_rendered(rgb), f"{distinct_colors(rgb)} colours, std {rgb.std():.1f}; {context}"

        # 2. the two KITTI frames, where the blueprint puts them: a left, b right, both in the top row
        gray = to_gray(rgb)
        h, w = gray.shape
        found = {}
        for view, x0, x1 in (("a", 0, w // 2), ("b", w // 2, w)):
            region = gray[: int(0.65 * h), x0:x1]
            score, scale, (x, y, bw, bh) = find_image(region, frames[view])
            control, _, _ = find_image(region, frames[view][::-1])  # the same frame upside down: no match
            found[view] = (score, scale, (x + x0, y, bw, bh))
            print(f"image {view}: correlation {score:.2f} (upside-down control {control:.2f}) at scale {scale:.2f}, "
                  f"box x={x + x0} y={y} {bw}x{bh}")
            assert score > 0.45 and score > control + 0.15, f"image {view} not found ({score:.2f} vs {control:.2f}); {context}"
            # the view fills most of its half of the screen (the blueprint's two equal columns)
            assert bw > 0.8 * (x1 - x0), (view, bw)
        assert abs(found["a"][1] - found["b"][1]) < 0.05, "image a and b shown at different scales"

        # 3. the recording's overlays on image a: epipolar lines / keypoints coloured green..red by residual
        x, y, bw, bh = found["a"][2]
        box = rgb[y: y + bh, x: x + bw].astype(int)
        r, g, b = box[..., 0], box[..., 1], box[..., 2]
        green = (g > 150) & (g > r + 60) & (g > b + 60)
        assert green.mean() > 0.01, f"only {green.mean():.2%} green overlay pixels on image a; {context}"
        # and the grayscale photo shows through (most pixels of the box are grey)
        grey = (np.abs(r - g) < 12) & (np.abs(g - b) < 12)
        assert grey.mean() > 0.5, f"{grey.mean():.2%} grey pixels in image a's box"

        # 4. the lower row (bar charts, histogram, metrics, summary) has content
        below = rgb[max(found["a"][2][1] + found["a"][2][3], int(0.6 * h)) + 40: h - 60]
        assert distinct_colors(below) > 100 and below.std() > 20, "the plot / summary row is empty"
    finally:
        if browser is not None:
            browser.close()
        if server is not None:
            server.close()
