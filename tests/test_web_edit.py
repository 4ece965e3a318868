"""Edit the matches in a real browser, as a user does: ``fviz inspect pair --web`` on KITTI odometry 00, temporal
frames 0 -> 1 (8-point fails on every match and holds once the matches off MAGSAC++'s F are out); headless Chromium
(software WebGL) loads the page. Checked on the screen and in the page:

- the edit tools' bar shows above the viewer (its pixels; ``body.editing``), every control inside the window (at
  1600 and at 1280 px wide), and the viewer fills the window below it (the bar covers no image);
- residual > 1 px under magsac, a real mouse click on "exclude": the matches excluded are those (SED under the
  recording's MAGSAC++ F), grey marks appear at both ends of each of them and nowhere else (screenshots before and
  after, where image a is found on the screen), the status line's verdict turns from "8point fails" to "no failure";
- a click on a keypoint of image a names its match on the toggle button; a click on the button excludes it;
- "reset" brings every match back (status, marks gone, verdict again).

The browser is slow (a frame every few seconds on a loaded machine): every wait is bounded by ``budget()``, no
assertion on time. Screenshots are saved under the test's tmp dir. Missing /usr/bin/chromium skips locally and fails
when CI=true.
"""

from __future__ import annotations

import json
import time

import cv2
import numpy as np
import pytest
from browser import Chromium, WebServer
from test_interactive_web import Page, open_page, shot
from test_web_viewer import budget, find_image, to_gray, viewer_rendered

from fviz.geometry import symmetric_epipolar_distance
from fviz.record import layout as L

pytestmark = [pytest.mark.browser, pytest.mark.kitti, pytest.mark.slow]

BAR = (0x1B, 0x1F, 0x22)  # the bar's background (page.html #tools)
CONTROLS = "#tools button, #tools input, #tools select"


def rect(b: Chromium, selector: str) -> list[float]:
    """[left, top, right, bottom] of the first element matching ``selector``."""
    return b.evaluate(f"(() => {{ const r = document.querySelector({json.dumps(selector)}).getBoundingClientRect();"
                      " return [r.left, r.top, r.right, r.bottom]; })()")


def press(b: Chromium, selector: str) -> None:
    """A real mouse click at the centre of the element on the screen."""
    x0, y0, x1, y1 = rect(b, selector)
    b.click(((x0 + x1) / 2, (y0 + y1) / 2), hover=0.3)


def until(b: Chromium, expression: str, timeout: float | None = None):
    """Poll a JavaScript expression until it is truthy (or the budget is spent) -> its last value."""
    end = time.monotonic() + (budget() if timeout is None else timeout)
    while True:
        value = b.evaluate(expression)
        if value or time.monotonic() > end:
            return value
        time.sleep(0.5)


def status_text(b: Chromium) -> str:
    return b.evaluate("document.getElementById('status').textContent")


def assert_bar_above_a_full_viewer(b: Chromium, rgb: np.ndarray | None = None) -> float:
    """The bar spans the window's top, every control inside it; the viewer's canvas fills the window below it.
    With a screenshot: the bar's own pixels (its background, text) in that band. -> the bar's height."""
    w, h = b.evaluate("[innerWidth, innerHeight]")
    assert b.evaluate("document.body.classList.contains('editing')"), "the edit tools are hidden"
    left, top, right, bar = rect(b, "#tools")
    assert (left, top, right) == (0, 0, w) and 40 <= bar <= 100, f"the bar: {[left, top, right, bar]} in {w}x{h}"
    cut = {c[0]: c[1:] for c in b.evaluate(
        f"[...document.querySelectorAll({json.dumps(CONTROLS)})].map(e => {{ const r = e.getBoundingClientRect();"
        " return [e.id, r.left, r.top, r.right, r.bottom]; })")
        if not (0 <= c[1] and c[3] <= w and 0 <= c[2] and c[4] <= bar)}
    assert not cut, f"controls outside the bar in a {w}-px window: {cut}"
    assert all(b.evaluate("[...document.querySelectorAll('#status span')].map(s => s.textContent.length > 20)")), status_text(b)
    canvas = rect(b, "canvas")
    assert canvas == [0, bar, w, h], f"the viewer does not fill the window below the bar ({bar} px): {canvas}"
    if rgb is not None:
        band = rgb[: int(bar)].astype(np.int16)
        background = float((np.abs(band - BAR).max(-1) < 12).mean())
        ink = int((band.mean(-1) > 160).sum())
        assert background > 0.5 and ink > 300, f"the bar's pixels: {background:.0%} background, {ink} px of text"
    return bar


def locate_a(rgb: np.ndarray, frame_a: np.ndarray) -> Page:
    """Image a on the screen (found at 0.01 steps of scale, then 0.001)."""
    score, s, _ = find_image(to_gray(rgb), frame_a)
    score, s, (x, y, _, _) = find_image(to_gray(rgb), frame_a, scales=np.arange(s - 0.01, s + 0.0101, 0.001))
    assert score > 0.5, f"image a not found on the screen (score {score:.2f})"
    return Page(x, y, s, (frame_a.shape[1], frame_a.shape[0]))


def grey_marks(before: np.ndarray, after: np.ndarray, ends: np.ndarray, r: int = 3, least: int = 8) -> np.ndarray:
    """(M,) bool: whether a grey mark (the excluded matches' colour, ``fviz.editing.EXCLUDED_COLOR``) appeared at
    each screen point of ``ends`` (M, 2): at least ``least`` pixels within ``r`` px that are that grey ``after``
    and were not ``before`` (a keypoint's colour, the photo). The image's place on the screen is known to ~2 px."""
    from fviz.editing import EXCLUDED_COLOR

    out = []
    for cx, cy in np.round(ends).astype(int):
        a = after[cy - r: cy + r + 1, cx - r: cx + r + 1].astype(np.int16)
        was = before[cy - r: cy + r + 1, cx - r: cx + r + 1].astype(np.int16)
        grey = (np.abs(a - EXCLUDED_COLOR).max(-1) < 25) & (np.ptp(a, axis=-1) < 12)
        out.append(int((grey & (np.abs(a - was).max(-1) > 30)).sum()) >= least)
    return np.array(out)


def exclude_above(b: Chromium, px: str, under: str) -> dict:
    """As a user: type ``px`` into the residual field (focused by a real click), choose ``under`` (the select's
    value set: a headless browser's drop-down is no part of the page), click "exclude" -> the status it brings."""
    press(b, "#px")
    assert b.evaluate("document.activeElement.id") == "px", "a click on the residual field did not focus it"
    b.evaluate("document.activeElement.select()")
    b.call("Input.insertText", {"text": px})
    b.evaluate(f"(() => {{ const s = document.getElementById('under'); s.value = {json.dumps(under)};"
               " s.dispatchEvent(new Event('change')); })()")
    assert b.evaluate("[document.getElementById('px').value, document.getElementById('under').value]") == [px, under]
    for _ in range(3):  # a click the page missed (a busy frame) is clicked again: the same edit
        press(b, "#above")
        if until(b, "window.fviz.status.excluded > 0", budget() / 3):
            break
    st = b.evaluate("window.fviz.status")
    assert st["excluded"] > 0, f"no match excluded: {st} {status_text(b)!r} {b.evaluate('window.fviz.message')}"
    return st


def wait_marks(b: Chromium, before: np.ndarray, ends: np.ndarray, done) -> tuple[np.ndarray, float]:
    """Screenshots until ``done(share of ends with a new grey mark)`` (or the budget is spent) -> (last, share)."""
    end = time.monotonic() + budget()
    while True:
        rgb = shot(b)
        share = float(grey_marks(before, rgb, ends).mean())
        if done(share) or time.monotonic() > end:
            return rgb, share
        time.sleep(1)


def click_match(b: Chromium, page: Page, fs, j: int) -> str:
    """Click match ``j``'s end in image a until the page hears of it -> the toggle button's text."""
    for _ in range(4):  # the viewer's first click can go to focusing its canvas
        b.click(page.screen("a", fs.x_a[j]))
        if until(b, f"window.fviz.click && window.fviz.click.match === {j}", budget() / 4):
            break
    return b.evaluate("document.getElementById('toggle').textContent")


def save(tmp_path, name: str, rgb: np.ndarray) -> None:
    cv2.imwrite(str(tmp_path / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    print(f"screenshot: {tmp_path / name}")


def test_exclude_by_residual_toggle_a_clicked_match_and_reset_with_the_pages_tools(kitti_root, tmp_path):
    from fviz.record.reader import column
    from fviz.record.rebuild import click_pairs

    out = tmp_path / "pair.rrd"
    inspect = ("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--frame", "0", "--pair", "temporal",
               "--out", out)
    t0 = time.monotonic()
    with WebServer(None, command=inspect, timeout=budget()) as server, Chromium(server.url) as b:
        blob = column(out, L.image("a"), "EncodedImage:blob")[0]
        frame_a = cv2.imdecode(np.frombuffer(bytes(blob[0] if isinstance(blob, list) else blob), np.uint8), 0)
        open_page(b, out, frame_a)  # the recording received, the viewer drawn
        assert until(b, "window.fviz.status"), f"no edit status reached the page: {b.console_errors()[:3]}"
        fs = click_pairs(out)[0]
        before = shot(b)
        save(tmp_path, "0-loaded.png", before)
        bar = assert_bar_above_a_full_viewer(b, before)
        page = locate_a(before, frame_a)
        assert page.y > bar, f"image a ({page.y:.0f} px from the top) under the bar ({bar} px)"
        first = b.evaluate("window.fviz.status")
        n = first["matches"]
        assert first["excluded"] == 0 and "8point fails" in status_text(b), status_text(b)

        # residual > 1 px under magsac, "exclude": the matches off MAGSAC++'s F by more, 8-point holds
        st = exclude_above(b, "1", "magsac")
        sed = symmetric_epipolar_distance(fs.F[fs.names.index("magsac")], fs.x_a, fs.x_b)
        out_ = np.array(st["excluded_matches"])
        off = np.setxor1d(out_, np.flatnonzero(sed > 1.0))
        assert np.all(np.abs(sed[off] - 1.0) < 1e-3), f"excluded {len(out_)}, SED > 1 px under magsac: {(sed > 1).sum()}"
        assert st["kept"] == n - len(out_) and st["verdict"].startswith("no failure"), st["verdict"]
        assert st["estimators"]["8point"]["trans_err_deg"] < 10 < first["estimators"]["8point"]["trans_err_deg"]
        assert "no failure" in status_text(b) and "8point fails" not in status_text(b), status_text(b)

        # grey marks at both ends of every excluded match, none at the kept ones'
        kept = np.setdiff1d(np.arange(n), out_)
        ends = lambda idx: np.concatenate([page.screen("a", fs.x_a[idx]), page.screen("b", fs.x_b[idx])])  # noqa: E731
        after, marked = wait_marks(b, before, ends(out_), lambda share: share >= 0.6)
        stray = grey_marks(before, after, ends(kept)).mean()
        save(tmp_path, "1-excluded.png", after)
        assert marked >= 0.6 and stray <= 0.1, (
            f"grey marks at {marked:.0%} of the excluded matches' ends, {stray:.0%} of the kept ones' ({tmp_path})")
        assert_bar_above_a_full_viewer(b, after)

        # a keypoint of image a clicked (a kept match far from every other end): the toggle button names it
        d = np.linalg.norm(fs.x_a[kept, None] - fs.x_a[None], axis=-1)
        d[np.arange(len(kept)), kept] = np.inf
        inside = np.all((fs.x_a[kept] > 60) & (fs.x_a[kept] < np.array(fs.size_a) - 60), axis=1)
        j = int(kept[np.argmax(np.where(inside, d.min(1), 0))])
        toggle = click_match(b, page, fs, j)
        assert toggle == f"exclude match {j}", f"{toggle!r} after a click on match {j}: {b.evaluate('window.fviz.click')}"
        save(tmp_path, "2-clicked.png", shot(b))
        press(b, "#toggle")
        assert until(b, f"window.fviz.status.excluded_matches.includes({j})"), f"match {j} not excluded: {status_text(b)!r}"
        st = b.evaluate("window.fviz.status")
        assert st["excluded"] == len(out_) + 1 and set(st["excluded_matches"]) == {*out_.tolist(), j}
        assert b.evaluate("document.getElementById('toggle').textContent") == f"restore match {j}"
        save(tmp_path, "3-toggled.png", shot(b))

        # reset: every match back, the marks gone, the first verdict again
        press(b, "#reset")
        assert until(b, "window.fviz.status.excluded === 0"), f"reset left {b.evaluate('window.fviz.status.excluded')}"
        assert "8point fails" in status_text(b), status_text(b)
        assert b.evaluate("window.fviz.status.verdict") == first["verdict"]
        reset, left = wait_marks(b, before, ends(out_), lambda share: share <= 0.1)
        save(tmp_path, "4-reset.png", reset)
        assert left <= 0.1, f"grey marks left at {left:.0%} of the excluded ends after reset ({tmp_path})"

        # a 1280-px window: every control still inside the bar, the viewer below it
        b.call("Emulation.setDeviceMetricsOverride", {"width": 1280, "height": 800, "deviceScaleFactor": 1, "mobile": False})
        png, rgb, _, _ = b.wait_stable(viewer_rendered, timeout=budget() / 2)
        save(tmp_path, "5-1280.png", rgb)
        assert_bar_above_a_full_viewer(b, rgb)
    print(f"scenario: {time.monotonic() - t0:.0f} s")
