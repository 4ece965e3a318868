"""End to end in a real browser: ``fviz open FILE --web [--tab NAME]`` serves a recording; headless Chromium
(software WebGL) loads the printed URL; screenshots are polled over the DevTools protocol until the viewer has
rendered and stopped changing; then the picture is checked as a person would check it:

- every screen: the viewer fills the window (fviz's page overrides the notebook widget's 16:9 box);
- the overview: both KITTI frames, image a above image b; the ground truth's white lines drawn over them; the
  comparison chart with a bar in every estimator's colour;
- one estimator's tab, clicked in the overview's page: both frames; lines in that estimator's colour and white
  ground-truth lines over them, no other estimator's colour anywhere on the frames, the keypoints in that
  estimator's residual classes; its numbers below the images;
- an eval recording: the metric series in every estimator's colour, the ground truth's white among them.

Overlays are told from the photo by comparing the screenshot with the real frame at the scale found. Each
screenshot is saved under the test's tmp dir; a failure names it. The time budget scales with the machine's
load (a loaded 2-core machine takes minutes to draw the viewer in software): ``FVIZ_BROWSER_TIMEOUT`` sets it.
Missing /usr/bin/chromium skips locally and fails when CI=true (``.ci/install-browser`` installs it).
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from browser import Chromium, WebServer, eval_run, inspect_recording, require_chromium, run_fviz

from fviz.record import layout as L
from fviz.record.placement import offset_b
from fviz.record.plots import log_values

pytestmark = [pytest.mark.browser, pytest.mark.kitti, pytest.mark.slow]

FRAMES = (3, 4)  # the pair inspected: odometry 00, temporal, frames 3 -> 4, camera 0
ESTIMATORS = ("8point", "ransac", "magsac")
COLORS = L.estimator_colors(["gt", *ESTIMATORS])
NEAR = 60.0  # RGB distance within which a pixel counts as a colour (anti-aliased line cores stay within)


def budget() -> float:
    """Seconds one viewer may take to settle: 150 s on an idle machine, times the load per core."""
    if "FVIZ_BROWSER_TIMEOUT" in os.environ:
        return float(os.environ["FVIZ_BROWSER_TIMEOUT"])
    load = os.getloadavg()[0] / (os.cpu_count() or 1)
    return 150.0 * min(max(1.0, load), 8.0)


def distinct_colors(rgb: np.ndarray, step: int = 16) -> int:
    q = (rgb // step).astype(np.int32)
    return len(np.unique(q[..., 0] * 65536 + q[..., 1] * 256 + q[..., 2]))


def viewer_rendered(rgb: np.ndarray) -> bool:
    """The viewer's panels are drawn: Rerun's loading and welcome screens have < 40 distinct colours (in 16-level
    bins) and a grey-level spread (std) < 10; fviz's screens 125 (triage's dark plots of points) to 470 (overview),
    std 24 to 60."""
    return distinct_colors(rgb) > 100 and float(rgb.std()) > 20


def find_image(gray: np.ndarray, image: np.ndarray, scales=np.arange(0.30, 1.301, 0.01)) -> tuple[float, float, tuple[int, int, int, int]]:
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


def near(rgb: np.ndarray, color, tol: float = NEAR) -> np.ndarray:
    """Mask of the pixels within ``tol`` of ``color``."""
    return np.linalg.norm(rgb.astype(np.float32) - np.asarray(color, np.float32), axis=-1) < tol


def overlay(rgb: np.ndarray, frame: np.ndarray, box: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(the screenshot's pixels inside ``box``, mask of those drawn over the photo: far from the frame's own
    grey at that place, compared at the scale found)."""
    import cv2

    x, y, w, h = box
    crop = rgb[y: y + h, x: x + w].astype(np.int16)
    photo = cv2.resize(frame, (crop.shape[1], crop.shape[0]), interpolation=cv2.INTER_AREA).astype(np.int16)
    # a few px of misregistration: a pixel is overlay only if it differs from the photo's whole neighbourhood
    lo = cv2.erode(photo.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(np.int16)
    hi = cv2.dilate(photo.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(np.int16)
    grey = crop.mean(-1)
    drawn = (grey < lo - 40) | (grey > hi + 40) | (np.ptp(crop, axis=-1) > 60)
    return crop.astype(np.uint8), drawn


def tab_centres(rgb: np.ndarray, n: int, gap: int = 8) -> list[tuple[int, int]]:
    """Screen centres of the ``n`` tab titles in the viewer's tab bar, left to right: the first run (from the top,
    below Rerun's top bar) of at least 3 bands of 12 rows whose ink (pixels far from the band's background, light or
    dark theme) makes exactly ``n`` groups more than ``gap`` px apart (a tab's icon and title are ~5 px apart, a
    highlighted tab's box ~9 px from the next title), the first at the window's left edge, in the left 60 % of the
    window (the bar's own icons are at its right end)."""
    left = rgb[:, : int(0.6 * rgb.shape[1])].astype(np.int16)
    runs: list[list] = []  # consecutive bands with n groups: [(top row of the band, its groups)]
    for y in range(40, rgb.shape[0] // 3, 2):
        band = left[y: y + 12]
        cols = np.flatnonzero((np.abs(band - np.median(band.reshape(-1, 3), 0)).max(-1) > 60).any(0))
        groups = np.split(cols, np.flatnonzero(np.diff(cols) > gap) + 1) if len(cols) else []
        if len(cols) and cols[0] <= 40 and len(groups) == n and all(len(g) > 4 for g in groups):
            if not runs or runs[-1][-1][0] != y - 2:
                runs.append([])
            runs[-1].append((y, groups))
    run = next((r for r in runs if len(r) >= 3), None)
    if run is None:
        raise AssertionError(f"no bar of {n} tabs found")
    y, groups = run[len(run) // 2]  # the band through the titles' middle
    return [(int(g[0] + g[-1]) // 2, y + 6) for g in groups]


class Shot:
    """A settled screenshot of ``fviz open FILE --web [extra]``, saved to ``path``. ``keep_open``: the page stays
    open (close it, or use ``with``) for :meth:`open_tab`, which clicks another tab as a user does."""

    def __init__(self, recording, path, *extra: str, keep_open: bool = False):
        require_chromium()
        self.recording = recording
        self.server = self.browser = None
        try:
            self.server = WebServer(recording, *extra)
            self.browser = Chromium(self.server.url)
            self._settle(path, viewer_rendered)
            canvas = self.browser.evaluate("(() => { const r = document.querySelector('canvas').getBoundingClientRect();"
                                           " return [r.left, r.top, r.width, r.height]; })()")
            assert canvas == [0, 0, *self.rgb.shape[1::-1]], f"the viewer does not fill the window: {canvas}; {self.context}"
            logged = [e["params"]["type"] for e in self.browser.events if e["method"] == "Runtime.consoleAPICalled"]
            assert "debug" not in logged and len(logged) < 100, f"{len(logged)} console lines ({logged.count('debug')} debug)"
        except BaseException:
            self.close()  # a failed start leaves no page or server behind (``with`` never got the object)
            raise
        if not keep_open:
            self.close()

    def _settle(self, path, ready, timeout: float | None = None, check: bool = True) -> None:
        timeout = budget() if timeout is None else timeout
        png, self.rgb, seconds, n = self.browser.wait_stable(ready, timeout=timeout, shot_timeout=timeout)
        self.path = path
        path.write_bytes(png)
        print(f"\nscreenshot: {path} ({self.rgb.shape[1]}x{self.rgb.shape[0]}, settled after {seconds:.0f} s, {n} shots)")
        self.context = (f"screenshot {path}; console errors: {self.browser.console_errors()[-3:]}; "
                        f"chromium log:\n{self.browser.log_tail()}")
        if check:
            assert seconds <= timeout, f"the viewer did not settle in {timeout:.0f} s; {self.context}"
            assert self.rgb.shape[:2] == (1000, 1600), self.rgb.shape
            assert viewer_rendered(self.rgb), f"{distinct_colors(self.rgb)} colours, std {self.rgb.std():.1f}; {self.context}"

    def open_tab(self, name: str, path, tries: int = 3) -> None:
        """Click tab ``name`` in the tab bar (found on the screen, in the recording's tab order), as a user does,
        until the screen changes; then settle again."""
        from fviz.record.reader import blueprint_tabs

        tabs = list(blueprint_tabs(self.recording))
        x, y = tab_centres(self.rgb, len(tabs))[tabs.index(name)]
        before = self.rgb.astype(np.int16)
        changed = lambda rgb: viewer_rendered(rgb) and float(np.abs(rgb.astype(np.int16) - before).mean()) > 2.0  # noqa: E731
        for attempt in range(tries):
            self.browser.click((x, y), hover=0.5)
            print(f"clicked tab {name!r} at ({x}, {y})")
            self._settle(path, changed, budget() / tries, check=attempt == tries - 1)
            if changed(self.rgb):
                return
        raise AssertionError(f"a click on tab {name!r} at ({x}, {y}) changed nothing; {self.context}")

    def close(self) -> None:
        browser, server, self.browser, self.server = self.browser, self.server, None, None
        if browser is not None:
            browser.close()
        if server is not None:
            server.close()

    def __enter__(self) -> "Shot":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def frames(self, frames: dict[str, np.ndarray], x_range=(0.0, 1.0)) -> dict[str, tuple[int, int, int, int]]:
        """Find both frames in the columns ``x_range`` (fractions of the width): a above b, same scale, large.
        -> {view: box}."""
        gray = to_gray(self.rgb)
        h, w = gray.shape
        x0, x1 = int(x_range[0] * w), int(x_range[1] * w)
        found = {}
        for view, (y0, y1) in (("a", (0, int(0.62 * h))), ("b", (int(0.38 * h), h))):
            region = gray[y0:y1, x0:x1]
            score, scale, (x, y, bw, bh) = find_image(region, frames[view])
            control, _, _ = find_image(region, frames[view][::-1])  # the same frame upside down: no match
            print(f"image {view}: correlation {score:.2f} (upside-down control {control:.2f}) at scale {scale:.2f}, "
                  f"box x={x + x0} y={y + y0} {bw}x{bh}")
            assert score > 0.45 and score > control + 0.15, f"image {view} not found ({score:.2f} vs {control:.2f}); {self.context}"
            assert bw > 0.55 * (x1 - x0), f"image {view} is small ({bw} px wide); {self.context}"
            found[view] = (scale, (x + x0, y + y0, bw, bh))
        (sa, (_, ya, _, ha)), (sb, (_, yb, _, _)) = found["a"], found["b"]
        assert abs(sa - sb) < 0.05, f"image a and b shown at different scales; {self.context}"
        assert ya + 0.9 * ha <= yb, f"image b is not below image a; {self.context}"
        return {v: box for v, (_, box) in found.items()}

    def count(self, color, box=None, mask=None) -> int:
        x, y, w, h = box or (0, 0, self.rgb.shape[1], self.rgb.shape[0])
        hit = near(self.rgb[y: y + h, x: x + w], color)
        return int((hit & mask).sum() if mask is not None else hit.sum())


SEPARATOR = (53, 52, 52)  # Rerun's panel borders (dark theme): full-width rows between views stacked vertically


def text_lines(rgb: np.ndarray, box: tuple[int, int, int, int]) -> list[tuple[int, int, int, int]]:
    """Lines of light text (Rerun's, on its dark panels) inside ``box`` (x, y, w, h): bands of rows holding light
    pixels, as (top row, bottom row, left, right) in screen coordinates."""
    x, y, w, h = box
    light = rgb[y: y + h, x: x + w].min(-1) > 140
    rows = np.flatnonzero(light.any(axis=1))
    bands = np.split(rows, np.flatnonzero(np.diff(rows) > 1) + 1) if len(rows) else []
    out = []
    for band in bands:
        cols = np.flatnonzero(light[band].any(axis=0))
        out.append((y + int(band[0]), y + int(band[-1]), x + int(cols[0]), x + int(cols[-1])))
    return out


def top_view_lines(rgb: np.ndarray) -> tuple[list[tuple[int, int, int, int]], int]:
    """The view at the top of the screen (between the first two full-width panel borders below Rerun's menu bar):
    its lines of text below its title (see :func:`text_lines`), and the row of the view's bottom border."""
    borders = np.flatnonzero(near(rgb, SEPARATOR, 8).mean(axis=1) > 0.9)
    top = int(borders[0])
    bottom = int(next(b for b in borders if b > top + 1))
    return text_lines(rgb, (0, top + 1, rgb.shape[1], bottom - top - 1))[1:], bottom  # [0]: its title and icons


def assert_verdict_line_inside(shot: "Shot", markdown, only: bool = True) -> None:
    """A verdict (its Markdown, ``**kind**: text``; or a list: any of them) is the first line of text of the view at
    the top, fully inside it: blank rows between it and the view's bottom border, short of the right edge, and as
    wide as its characters make it (5-7.5 px each in the viewer's font); ``only``: the view holds that one line."""
    texts = [m.replace("**", "") for m in ([markdown] if isinstance(markdown, str) else markdown)]
    lines, bottom = top_view_lines(shot.rgb)
    print(f"top view: lines {lines}, bottom border at row {bottom}; verdicts {texts}")
    assert lines, f"no text in the view at the top; {shot.context}"
    y0, y1, x0, x1 = lines[0]
    assert y1 <= bottom - 3, f"the verdict line (rows {y0}-{y1}) is cut by the view's border at {bottom}; {shot.context}"
    assert x1 <= shot.rgb.shape[1] - 10, f"the verdict line runs to the right edge ({x1}); {shot.context}"
    assert any(5.0 <= (x1 - x0) / len(t) <= 7.5 for t in texts), \
        f"the first line ({x1 - x0} px) is not a verdict ({[len(t) for t in texts]} chars); {shot.context}"
    assert not only or len(lines) == 1, f"the verdict is not one line: {lines}; {shot.context}"


def residual_sides(crop: np.ndarray, drawn: np.ndarray, tol: float = 20.0, dot: int = 8) -> tuple[int, int]:
    """Overlay pixels of the keypoints' residual scale, as (near the line: bins 0-1, mid-way: bins 3-6) by the
    nearest bin colour within ``tol``, in dots (pieces at most ``dot`` px across: a keypoint is ~5)."""
    import cv2

    bins = L.class_color(np.arange(L.RESIDUAL_CLASSES)).astype(np.float32)
    # not at the lines, whose anti-aliased edges blend with the photo into teal or violet (and, under a label's
    # translucent box, a line dimmed to teal is no dot either)
    lines = np.any([near(crop, c) for c in COLORS.values()], axis=0).astype(np.uint8)
    drawn = drawn & ~cv2.dilate(lines, np.ones((7, 7), np.uint8)).astype(bool)
    dist = np.linalg.norm(crop.astype(np.float32)[..., None, :] - bins, axis=-1)
    nearest = np.where(drawn & (dist.min(-1) < tol), dist.argmin(-1), -1)

    def dots(mask: np.ndarray) -> int:
        n, _, st, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8))
        return int(sum(st[i, 4] for i in range(1, n) if max(st[i, 2], st[i, 3]) <= dot))

    return dots(np.isin(nearest, (0, 1))), dots(np.isin(nearest, (3, 4, 5, 6)))


def class_sides(classes) -> tuple[int, int]:
    """The same split of the matches from their recorded classes (one end of each match)."""
    bins = np.asarray(classes[: len(classes) // 2]) % L.RESIDUAL_CLASSES
    return int(np.isin(bins, (0, 1)).sum()), int(np.isin(bins, (3, 4, 5, 6)).sum())


def assert_keypoints_in_classes_of(name: str, recording, shot: "Shot", crops: dict) -> None:
    """The keypoints drawn are coloured by ``name``'s residuals: the balance of near-the-line and mid-way
    colours on screen leans the way the recorded classes of ``name`` do (the ground truth and the robust
    estimators lean opposite ways on this pair, so showing another's classes fails)."""
    from fviz.record.rebuild import match_classes

    near_line, mid = class_sides(match_classes(recording)[name])
    assert max(near_line, mid) > 3 * min(near_line, mid), f"{name}: {near_line} vs {mid} matches: not a telling pair"
    seen = [residual_sides(*crops[v]) for v in crops]
    print(f"{name}'s keypoints: {near_line} near the line vs {mid} mid-way; on screen (pixels) {seen}")
    for (s_near, s_mid), v in zip(seen, crops):
        assert (s_near > s_mid) == (near_line > mid) and s_near + s_mid > 200, \
            f"image {v}: keypoint colours {s_near} near vs {s_mid} mid-way, {name}'s classes {near_line} vs {mid}; {shot.context}"


@pytest.fixture(scope="module")
def inspected(kitti_root, tmp_path_factory):
    return inspect_recording(kitti_root, tmp_path_factory.mktemp("web") / "pair.rrd")[0]


@pytest.fixture(scope="module")
def pair_frames(odometry):
    pair = odometry.pair(FRAMES[0], "temporal")
    return {"a": to_gray(pair.image_a), "b": to_gray(pair.image_b)}


def test_overview_then_a_click_on_an_estimator_tab(inspected, pair_frames, tmp_path):
    """The overview (:func:`assert_overview_shows_both_frames_the_ground_truth_and_the_comparison`); then, in the
    same page, a click on ransac's tab (:func:`assert_estimator_tab_shows_that_estimator_alone`)."""
    with Shot(inspected, tmp_path / "overview.png", keep_open=True) as shot:
        assert_overview_shows_both_frames_the_ground_truth_and_the_comparison(shot, inspected, pair_frames)
        shot.open_tab("ransac", tmp_path / "tab-ransac.png")
        assert_estimator_tab_shows_that_estimator_alone(shot, "ransac", inspected, pair_frames)


def assert_overview_shows_both_frames_the_ground_truth_and_the_comparison(shot: "Shot", inspected, pair_frames) -> None:
    from fviz.record.reader import text

    assert_verdict_line_inside(shot, text(inspected, L.VERDICT)[0])  # above the tabs: "estimator: 8point fails ..."
    boxes = shot.frames(pair_frames, (0.0, 0.72))
    white, crops = {}, {}
    for v, box in boxes.items():
        crop, drawn = crops[v] = overlay(shot.rgb, pair_frames[v], box)
        white[v] = int((near(crop, COLORS["gt"]) & drawn).sum())
        assert white[v] > 300, f"{white[v]} white ground-truth line pixels on image {v}; {shot.context}"
    assert_keypoints_in_classes_of("gt", inspected, shot, crops)
    assert_scale_end_labels_whole(shot, boxes)
    # the comparison chart (right column, top): one bar per F in its colour, the ground truth's white included
    h, w = shot.rgb.shape[:2]
    chart = (int(0.72 * w), 60, w - int(0.72 * w), int(0.5 * h))
    for name, color in COLORS.items():
        n = shot.count(color, chart)
        assert n > 150, f"{n} pixels of {name}'s colour {color} in the comparison chart; {shot.context}"
    print(f"white line pixels {white}")
    # every F's epipole glyph drawn where the recording puts it (over the lines, in its colour)
    from fviz.record import reader as R

    for v, box in boxes.items():
        scale = box[2] / pair_frames[v].shape[1]
        strips = R.column(inspected, L.epipoles(v), "LineStrips2D:strips")[0]
        labels = R.column(inspected, L.epipoles(v), "LineStrips2D:labels")[0]
        for name, color in COLORS.items():
            pts = np.concatenate([np.array(st) for st, lab in zip(strips, labels) if lab.startswith(f"{name}: epipole")][:-1])
            cx, cy = (pts.min(0) + pts.max(0)) / 2
            sx, sy = int(box[0] + (cx + 0.5) * scale), int(box[1] + (cy + 0.5) * scale)
            window = (max(sx - 16, 0), max(sy - 16, 0), 32, 32)
            n = shot.count(color, window)
            print(f"image {v}: {name}'s epipole glyph at screen ({sx}, {sy}): {n} pixels of its colour")
            assert n > 12, f"{name}'s epipole glyph not visible on image {v} ({n} px at {sx}, {sy}); {shot.context}"


def assert_estimator_tab_shows_that_estimator_alone(shot: "Shot", name: str, inspected, pair_frames) -> None:
    """Both frames; lines in that estimator's colour and white ground-truth lines over them, no other estimator's
    colour on the frames, the keypoints in its residual classes (the blueprint's override); below image b its
    numbers and the residual scale, not cut."""
    boxes = shot.frames(pair_frames)
    counts, crops = {}, {}
    for v, box in boxes.items():
        crop, drawn = crops[v] = overlay(shot.rgb, pair_frames[v], box)
        counts[v] = {n: int((near(crop, c) & drawn).sum()) for n, c in COLORS.items()}
        print(f"image {v}: overlay pixels per colour {counts[v]}")
        assert counts[v][name] > 1000, f"too few {name} line pixels on image {v}: {counts[v]}; {shot.context}"
        assert counts[v]["gt"] > 300, f"too few white ground-truth line pixels on image {v}: {counts[v]}; {shot.context}"
        for other in ESTIMATORS:
            if other != name:
                assert counts[v][other] < 0.02 * counts[v][name], \
                    f"{other}'s colour on the {name} tab, image {v}: {counts[v]}; {shot.context}"
    assert_keypoints_in_classes_of(name, inspected, shot, crops)  # its classes (the blueprint's override), not gt's
    # below image b, not cut: the estimator's numbers (a label, its text in LABEL_OFF_PHOTO) and the residual scale
    x, y, w, h = boxes["b"]
    caption = shot.rgb[y + h + 4: y + h + 30, x + w // 4: x + 3 * w // 4]
    box = int(sum((np.abs(caption.astype(int) - np.array(c)).max(-1) <= 3).sum() for c in LABEL_BOXES))
    text = int(near(caption, L.LABEL_OFF_PHOTO, 40).sum())  # the label's text on its box (dark or light theme)
    scale = shot.rgb[y + h + 30: y + h + 62, x: x + w]
    bins = [int(near(scale, c, 25).sum()) for c in L.class_color(np.arange(L.RESIDUAL_CLASSES))]
    print(f"below image b: {box} label-box and {text} text pixels in the caption band, residual scale pixels per bin {bins}")
    assert y + h + 62 <= shot.rgb.shape[0] - 30, f"image b and its footer run into the time panel; {shot.context}"
    assert box > 2000 and text > 100, f"no numbers below image b ({box} label-box, {text} text pixels); {shot.context}"
    assert sum(b > 20 for b in bins) >= L.RESIDUAL_CLASSES - 2, f"residual scale missing below image b: {bins}; {shot.context}"


def assert_scale_end_labels_whole(shot: "Shot", boxes: dict) -> None:
    """Below the images (``boxes``: {view: (x, y, w, h)} on screen, the overview), the residual scale's two end
    labels whole, never cut by the time panel (Rerun's label boxes: grey LABEL_BOX, dark text, ~23 px high)."""
    import cv2

    x0, x1 = min(b[0] for b in boxes.values()), max(b[0] + b[2] for b in boxes.values())
    bottom = max(b[1] + b[3] for b in boxes.values())
    band = shot.rgb[bottom: bottom + 120, x0: x1].astype(int)
    n, _, st, _ = cv2.connectedComponentsWithStats((np.abs(band - LABEL_BOX).max(-1) <= 3).astype(np.uint8))
    ends = sorted((int(st[i, 0]), int(st[i, 3])) for i in range(1, n) if st[i, 4] > 1000)  # (left, height)
    print(f"residual scale's end labels below the images (left x, height): {ends}")
    assert len(ends) == 2 and all(eh >= 18 for _, eh in ends), f"scale labels cut or missing: {ends}; {shot.context}"


LABEL_BOX = (28, 28, 28)  # the box of a label Rerun draws beside a mark, over the view's background (dark theme)
LABEL_BOXES = (LABEL_BOX, (239, 239, 239))  # dark theme, light theme
VIEW_SEPARATOR = (53, 52, 52)  # the viewer's 2 px lines between views


def plot_boxes(rgb: np.ndarray, min_size: int = 120) -> list[tuple[int, int, int, int]]:
    """The dark plot backgrounds (layout.CHART_BACKGROUND) of a screen, row by row: [(x, y, w, h)]."""
    import cv2

    mask = near(rgb, L.CHART_BACKGROUND, 12).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((9, 9), np.uint8))  # through the series drawn on it
    mask[near(rgb, VIEW_SEPARATOR, 4)] = 0  # the closing bridges the 2 px between two views: cut them apart again
    n, _, stats, _ = cv2.connectedComponentsWithStats(mask)
    boxes = [tuple(int(v) for v in stats[i, :4]) for i in range(1, n) if min(stats[i, 2], stats[i, 3]) >= min_size]
    return sorted(boxes, key=lambda b: (b[1] // 100, b[0]))


# A series line is 1 px, anti-aliased over two rows: at a sub-pixel height neither row is within 50 of its colour
# (a flat line: 145 of 385 columns at 50, 263 at 80). 80 is still far from any other series' colour (the nearest
# pair, magsac's orange and deep's red, are 125 apart).
LINE_NEAR = 80


def track(rgb: np.ndarray, box, color) -> tuple[int, float]:
    """(pixels of a series' colour in a plot, spread of its line: 10-90 % range of its per-column median height)."""
    x, y, w, h = box
    hit = near(rgb[y: y + h, x: x + w], color, LINE_NEAR)
    cols = [np.median(np.flatnonzero(hit[:, c])) for c in range(w) if hit[:, c].any()]
    return int(hit.sum()), (float(np.percentile(cols, 90) - np.percentile(cols, 10)) if len(cols) > 10 else 0.0)


@pytest.fixture(scope="module")
def deep_run(kitti_root, tmp_path_factory):
    """Sequence 00, pairs 0..11, with 8-point's wild epipoles and the network's near-constant ones."""
    return eval_run(kitti_root, tmp_path_factory.mktemp("runs") / "run", "0:12", (*ESTIMATORS, "deep"))


def assert_motion_separates_the_flat_network_from_the_moving_truth(shot: Shot) -> None:
    """eval.rrd's motion tab with 8point in the run: the ground truth's epipole moves, the network's stays flat,
    and both are readable beside each other (ranges that leave 8-point's swings off-scale); the plots' legends
    are hidden and one legend view holds every series' colour."""
    boxes = plot_boxes(shot.rgb)
    print(f"plots {boxes}")
    assert len(boxes) >= 6, f"{len(boxes)} plots; {shot.context}"
    colors = L.estimator_colors(["gt", *ESTIMATORS, "deep"])
    gt, deep = track(shot.rgb, boxes[0], colors["gt"]), track(shot.rgb, boxes[0], colors["deep"])  # epipole x
    print(f"epipole x: ground truth {gt[0]} px spread {gt[1]:.0f}; deep {deep[0]} px spread {deep[1]:.0f}")
    assert gt[0] > 150 and deep[0] > 150, f"a track is missing: gt {gt}, deep {deep}; {shot.context}"
    assert gt[1] > 40 and gt[1] > 4 * deep[1], f"the flat track is not told from the truth: gt {gt}, deep {deep}; {shot.context}"
    legend = boxes[-1]  # the last view of the grid
    for name, color in colors.items():
        assert shot.count(color, legend) > 100, f"{name} missing from the legend view; {shot.context}"


def blobs(rgb: np.ndarray, box, color, tol: float = 50) -> list[tuple[float, float, int]]:
    """Connected pieces of a colour inside a plot: [(centre x, centre y, pixels)], left to right."""
    import cv2

    x, y, w, h = box
    n, _, st, c = cv2.connectedComponentsWithStats(near(rgb[y: y + h, x: x + w], color, tol).astype(np.uint8))
    return sorted((float(c[i, 0]), float(c[i, 1]), int(st[i, 4])) for i in range(1, n) if st[i, 4] >= 6)


def test_triage_opens_on_rank_worst_first(deep_run, tmp_path):
    """triage.rrd plots per rank, as points (neighbouring ranks are unrelated pairs: no line joins them): the
    ranked estimator's points fall from left (rank 0, the worst) to right, one apart from the next; no motion tab."""
    from fviz.record.reader import blueprint_tabs

    r = run_fviz("triage", "--out-dir", deep_run, "--by", "8point", "--top", "8", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "motion" not in blueprint_tabs(deep_run / "triage.rrd")
    shot = Shot(deep_run / "triage.rrd", tmp_path / "triage.png", "--tab", "metrics")
    from fviz.record.reader import text

    banners = text(deep_run / "triage.rrd", L.TRIAGE_TAGS)  # each opens with its pair's verdict, never cut by its height
    assert_verdict_line_inside(shot, [b.split("\n")[0] for b in banners], only=False)
    box = min(plot_boxes(shot.rgb), key=lambda b: b[0] + b[1])  # the top-left plot: median SED
    dots = [b for b in blobs(shot.rgb, box, COLORS["8point"]) if b[2] < 400]  # a marker, not a title or a line
    xs, ys = np.array([(bx, by) for bx, by, _ in dots]).T if dots else (np.zeros(0), np.zeros(0))
    rho = float(np.corrcoef(np.argsort(np.argsort(xs)), np.argsort(np.argsort(ys)))[0, 1]) if len(dots) > 2 else 0.0
    hit = near(shot.rgb[box[1]: box[1] + box[3], box[0]: box[0] + box[2]], COLORS["8point"], 50)
    span = np.ptp(xs) if len(xs) else 0.0
    print(f"8point's SED over the ranks: {len(dots)} points {[(int(a), int(b)) for a, b, _ in dots]}, rank correlation "
          f"of x and depth {rho:.2f}; its colour in {int(hit.any(0).sum())} columns over {span:.0f}")
    assert len(dots) >= 6 and rho > 0.8, f"8point's points do not fall rank by rank ({len(dots)}, rho {rho:.2f}); {shot.context}"
    assert hit.any(0).sum() < 0.3 * span, f"a line joins 8point's ranks ({int(hit.any(0).sum())} columns); {shot.context}"


@pytest.fixture(scope="module")
def turn_run(kitti_root, tmp_path_factory):
    """Sequence 01, pairs 0..11: a highway turn (2.5 deg a frame), where the constant straight-ahead F is ~30x
    worse than MAGSAC and RANSAC in median SED."""
    out = tmp_path_factory.mktemp("turn") / "run"
    r = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "01", "--pair", "temporal", "--frames", "0:12",
                 "-e", "ransac", "-e", "magsac", "-e", "ahead", "--workers", "1", "--no-progress", "--out-dir", out, timeout=600)
    assert r.returncode == 0, r.stderr
    return out


def test_a_failing_estimator_is_drawn_inside_the_error_plots(turn_run, tmp_path):
    """eval.rrd's metrics on a turn: the errors on log10 axes hold the failing estimator (ahead, ~30x worse) and the
    best ones in one range: in the median SED plot ahead's series is drawn, well above MAGSAC's and RANSAC's, which
    are drawn too; the plot's range holds every value the recording has."""
    from fviz.record import rebuild as R

    rrd = turn_run / "eval.rrd"
    sed = {n: np.nanmedian(v) for n, v in R.series_values(rrd, L.metric("sed_median")).items()}
    assert sed["ahead"] > 10 * max(sed["ransac"], sed["magsac"]), f"not a failing estimator: {sed}"
    lo, hi, cut = R.series_ranges(rrd)[L.metric_plot("sed_median")]
    logs = np.concatenate([log_values(v) for v in R.series_values(rrd, L.metric("sed_median")).values()])
    assert not cut and lo < np.nanmin(logs) and np.nanmax(logs) < hi, (lo, hi, cut)
    shot = Shot(rrd, tmp_path / "turn-metrics.png", "--tab", "metrics")
    box = min(plot_boxes(shot.rgb), key=lambda b: b[0] + b[1])  # the top-left plot: median SED
    colors = L.estimator_colors(["gt", "ransac", "magsac", "ahead"])
    heights = {}
    for name in ("ahead", "ransac", "magsac"):
        n, _ = track(shot.rgb, box, colors[name])
        x, y, w, h = box
        rows = np.flatnonzero(near(shot.rgb[y: y + h, x: x + w], colors[name], LINE_NEAR).any(1))
        heights[name] = float(np.median(rows)) if len(rows) else -1.0
        print(f"{name}: {n} pixels in the median SED plot {box}, median row {heights[name]:.0f}")
        assert n > 150, f"{name}'s series is not drawn inside the plot ({n} px); {shot.context}"
    assert heights["ahead"] + 0.25 * box[3] < min(heights["ransac"], heights["magsac"]), \
        f"ahead is not drawn well above the robust estimators: {heights}; {shot.context}"


# ---------------------------------------------------------------------------------------------- issue 18: legends, reference


def legend_bars(rgb: np.ndarray, colors: dict) -> dict[str, tuple[int, int, int, int]]:
    """The legend view's rows (layout.LEGEND): per series the thick bar in its colour, (x, y, w, h), where one is
    found (a filled bar 30-150 px wide, 6-30 px high: a series line is thin, a view's white title bar wider)."""
    import cv2

    out = {}
    for name, color in colors.items():
        n, _, st, _ = cv2.connectedComponentsWithStats(near(rgb, color, 40).astype(np.uint8))
        bars = [tuple(int(v) for v in st[i, :4]) for i in range(1, n)
                if 30 <= st[i, 2] <= 150 and 6 <= st[i, 3] <= 30 and st[i, 4] >= 0.7 * st[i, 2] * st[i, 3]]
        if bars:
            out[name] = max(bars, key=lambda b: b[2] * b[3])
    return out


def legend_stacks(rgb: np.ndarray, colors: dict, outside=None) -> list[list[tuple[str, float, float]]]:
    """Plot legends drawn over a plot (egui's: a column of small filled swatches, one per series, beside the
    names): groups of >= 3 series whose compact blobs (5-16 px, at least half filled) sit in one column (x within
    4 px) less than 150 px apart. ``outside``: a box (x, y, w, h) left out (fviz's own legend view)."""
    import cv2

    blobs = []
    for name, color in colors.items():
        mask = near(rgb, color, 50).astype(np.uint8)
        if outside is not None:
            x, y, w, h = outside
            mask[y: y + h, x: x + w] = 0
        n, _, st, _ = cv2.connectedComponentsWithStats(mask)
        blobs += [(name, st[i, 0] + st[i, 2] / 2, st[i, 1] + st[i, 3] / 2) for i in range(1, n)
                  if 5 <= st[i, 2] <= 16 and 5 <= st[i, 3] <= 16 and st[i, 4] >= 0.5 * st[i, 2] * st[i, 3]]
    stacks = []
    for name, x, y in blobs:
        column = [b for b in blobs if abs(b[1] - x) <= 4 and abs(b[2] - y) < 150]
        if len({b[0] for b in column}) >= 3:
            stacks.append(column)
    return stacks


def assert_legend_covers_no_data(shot: Shot) -> None:
    """eval.rrd's metrics tab: every series' name is in the legend view (a bar in its colour each, one column, in
    the recording's order) and the legend's box holds no series line; no plot draws a legend of its own over
    its data (a column of series swatches, as egui's plot legend draws them)."""
    colors = L.estimator_colors(["gt", *ESTIMATORS, "deep"])
    bars = legend_bars(shot.rgb, colors)
    print(f"legend bars {bars}")
    assert set(bars) == set(colors), f"legend rows missing: {set(colors) - set(bars)}; {shot.context}"
    xs, ys = [b[0] for b in bars.values()], [bars[n][1] for n in colors]
    assert max(xs) - min(xs) <= 4 and ys == sorted(ys), f"legend rows not one column in order: {bars}; {shot.context}"
    x0, y0 = min(xs) - 12, min(ys) - 12
    right, bottom = max(b[0] + b[2] for b in bars.values()) + 12, max(b[1] + b[3] for b in bars.values()) + 12
    box = (x0, y0, right + 200 - x0, bottom - y0)  # the bars and their names
    x, y, w, h = column = (x0, y0, right - x0, bottom - y0)  # the bars alone (the names are white text)
    inside = shot.rgb[y: y + h, x: x + w]
    lines = {n: int(near(inside, c, 50).sum()) - bars[n][2] * bars[n][3] for n, c in colors.items()}
    data = {n: shot.count(c) - shot.count(c, box) for n, c in colors.items()}
    print(f"legend {box}: series pixels among its bars {column} beyond the bars {lines}; outside the legend {data}")
    assert all(v > 150 for v in data.values()), f"a series is missing from the plots: {data}; {shot.context}"
    assert all(v < 0.1 * bars[n][2] * bars[n][3] for n, v in lines.items()), \
        f"series lines over the legend's bars {column}: {lines}; {shot.context}"
    stacks = legend_stacks(shot.rgb, colors, outside=box)
    assert not stacks, f"a plot draws its own legend over its data: {stacks[0]}; {shot.context}"


def test_run_metrics_tab_then_a_click_on_the_motion_tab(deep_run, tmp_path):
    """eval.rrd opened on its metrics tab (:func:`assert_legend_covers_no_data`); then, in the same page, a click on
    the motion tab as a user clicks it (:func:`assert_motion_separates_the_flat_network_from_the_moving_truth`)."""
    with Shot(deep_run / "eval.rrd", tmp_path / "metrics.png", "--tab", "metrics", keep_open=True) as shot:
        assert_legend_covers_no_data(shot)
        shot.open_tab("motion", tmp_path / "motion.png")
        assert_motion_separates_the_flat_network_from_the_moving_truth(shot)


def test_suspect_ground_truth_overview_draws_the_reference(kitti_root, odometry, tmp_path):
    """Pair 7 -> 8 (its ground truth suspect, the reference magsac): the overview draws magsac's lines, in its
    colour, where the recording's ``reference`` strips lie, on both frames, and labels them; ransac (the other
    robust F, not the reference) has no lines there."""
    import json

    from fviz.record import reader as R

    rrd = tmp_path / "suspect.rrd"
    r = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frame", "7",
                 "--out", rrd, "--json")
    assert r.returncode == 0, r.stderr
    notes = json.loads(r.stdout)["notes"]
    assert any(n.startswith("gt-suspect: ") and n.endswith("(reference: magsac)") for n in notes), notes
    pair = odometry.pair(7, "temporal")
    frames = {"a": to_gray(pair.image_a), "b": to_gray(pair.image_b)}
    shot = Shot(rrd, tmp_path / "suspect-overview.png")
    boxes = shot.frames(frames, (0.0, 0.72))
    strips = [np.asarray(s, float) for s in R.column(rrd, L.REFERENCE, "LineStrips2D:strips")[0]]
    labels = R.column(rrd, L.REFERENCE, "LineStrips2D:labels")[0]
    shift = offset_b(pair.size_a)
    for v, box in boxes.items():
        crop, drawn = overlay(shot.rgb, frames[v], box)
        ref, other = (int((near(crop, COLORS[n]) & drawn).sum()) for n in ("magsac", "ransac"))
        scale = box[2] / frames[v].shape[1]
        mine = [s - (shift if v == "b" else 0) for s, lab in zip(strips, labels)
                if not lab and (s[:, 1].max() > pair.size_a[1]) == (v == "b")]  # a's lines end above its bottom row
        hits = total = 0
        for p, q in mine:  # along each reference line, its colour on screen
            for t in np.linspace(0.05, 0.95, 19):
                at = p + t * (q - p)
                sx, sy = int(box[0] + (at[0] + 0.5) * scale), int(box[1] + (at[1] + 0.5) * scale)
                hits += shot.count(COLORS["magsac"], (sx - 2, sy - 2, 5, 5)) > 0
                total += 1
        print(f"image {v}: {ref} magsac pixels, {other} ransac pixels; {hits} of {total} points along the "
              f"{len(mine)} reference lines in magsac's colour")
        assert len(mine) >= 5 and hits > 0.75 * total, f"image {v}: reference lines not drawn ({hits}/{total}); {shot.context}"
        assert ref > 1500 and other < 0.1 * ref, f"image {v}: magsac {ref} vs ransac {other} pixels; {shot.context}"
        # its label near the top right of the frame (Rerun draws it just below its point): black text drawn over
        # the photo (no line, keypoint or line edge is black; elsewhere along that row: 0 or 1 such pixels)
        lx, ly = int(0.8 * frames[v].shape[1] * scale), int(22 * scale)
        text = int((drawn & (crop.max(-1) < 70))[ly - 4: ly + 26, lx - 150: lx + 150].sum())
        print(f"image {v}: {text} black text pixels around ({lx}, {ly}) of the frame")
        assert text > 100, f"image {v}: no REFERENCE label at ({lx}, {ly}) of the frame ({text} px); {shot.context}"
