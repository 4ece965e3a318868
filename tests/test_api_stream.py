"""Many pairs logged with the public API into one stream (``fviz.log_result(rec, pair, result, index=i)``)
behave as an ``eval --full`` recording's: the layout opens on the ``pair`` timeline; at pair i only pair i's entities
are live (an F only pair 0 has is cleared after it); each index has its own F's, sizes and keypoints, and a click at
the time cursor on pair i is answered with pair i's lines (OpenCV's); the views frame every pair, of two sizes.
Read back from the saved .rrd with Rerun's own reader; the live entities are computed here (latest row at or before
the time, a ``Clear`` hiding its entity), independently of fviz."""

from __future__ import annotations

import json
import warnings

import cv2
import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

import fviz
from fviz.errors import FvizError
from fviz.interactive import SNAP_PX
from fviz.record import layout as L
from fviz.record.placement import screen_unit
from fviz.record import reader as R
from fviz.record.placement import images_extent
from fviz.record.rebuild import click_pairs, recording_blueprint

N_PAIRS = 4
SMALL = 0.6  # pairs 1 and 3: the synthetic scene resized (another image size, the same geometry)


def _resized(p, s: float):
    """The pair at scale ``s`` (pixel centres kept: x' = s (x + 0.5) - 0.5), its K's scaled, the same pose."""
    S = np.array([[s, 0, 0.5 * s - 0.5], [0, s, 0.5 * s - 0.5], [0, 0, 1.0]])
    a, b = (cv2.resize(im, None, fx=s, fy=s, interpolation=cv2.INTER_AREA) for im in (p.image_a, p.image_b))
    return fviz.pair_from_images(a, b, K_a=S @ p.K_a, K_b=S @ p.K_b, R=p.R, t=p.t, name=f"small{s:g}")


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """Four synthetic pairs (1242x375 and 745x225 alternately) logged at indices 0..3 into a stream saved to a file;
    pair 0 alone has the user's F "mine"."""
    path = tmp_path_factory.mktemp("stream") / "pairs.rrd"
    pairs, results = [], []
    rec = rr.RecordingStream("my-eval")
    rec.save(str(path))
    for i in range(N_PAIRS):
        p = fviz.load_pair(synthetic=True, seed=i)
        p = _resized(p, SMALL) if i % 2 else p
        r = fviz.inspect_pair(p, ("8point",), F={"mine": p.F_gt} if i == 0 else None)
        fviz.log_result(rec, p, r, index=i, lines=10, probe=3)
        pairs.append(p)
        results.append(r)
    rec.flush()
    rec.disconnect()
    assert len({p.size_a for p in pairs}) == 2
    return path, pairs, results


def _rows(path) -> dict[str, list[tuple[int, bytes, bool]]]:
    """{entity: [(pair time, row id, is a Clear)]} of every temporal row on ``pair``."""
    out: dict[str, list] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for ch in RrdReader(path).stream().to_chunks():
            rb = ch.to_record_batch()
            if L.TIMELINE not in rb.schema.names:
                continue
            clear = "Clear:is_recursive" in rb.schema.names
            rows = zip(rb.column(L.TIMELINE).to_pylist(), rb.column("rerun.controls.RowId").to_pylist())
            out.setdefault(ch.entity_path.strip("/"), []).extend((t, rid, clear) for t, rid in rows if t is not None)
    return out


def _live(rows, i: int) -> dict[str, int]:
    """{entity: the pair time of its row shown at pair = i} (latest at or before i, by time then row id; a Clear
    there hides the entity)."""
    out = {}
    for ent, rs in rows.items():
        before = [r for r in rs if r[0] <= i]
        if before:
            t, _, clear = max(before, key=lambda r: (r[0], r[1]))
            if not clear:
                out[ent] = t
    return out


def _last_blueprint(path) -> dict[str, list]:
    """{component: values} of the blueprint sent last into the file (the viewer makes each sent one active); its
    store found by where its id first appears in the file's bytes (RrdReader lists the stores by id)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = RrdReader(path)
        data = path.read_bytes()
        store = max(reader.blueprints(), key=lambda s: data.find(s.recording_id.encode()))
        out: dict[str, list] = {}
        for ch in reader.stream(store=store).to_chunks():
            rb = ch.to_record_batch()
            for n in (n for n in rb.schema.names if ":" in n):  # components, not the indices
                out.setdefault(n.split(":")[-1], []).extend(v for v in rb.column(n).to_pylist() if v is not None)
    return out


def _image_views(bp) -> list[dict]:
    """The bounds of the images' views: their margin alike left and above (not the comparison chart), wider than
    the probe's zooms."""
    return [b for row in bp["range"] for b in row if b["x_range"][0] == b["y_range"][0] and b["x_range"][1] > 200]


def test_the_page_opens_on_the_pair_timeline_and_frames_every_pair(logged, tmp_path):
    """(a) the time panel on ``pair``, as eval's; (d) one blueprint per recording (Rerun 0.41): its image views frame
    the largest pair, so that the big pairs are not cut by the last (small) pair's bounds. ``fviz open --tab``
    rebuilds the same from the file."""
    path, pairs, _ = logged
    bp = _last_blueprint(path)
    assert bp["timeline"] == [[L.TIMELINE]]
    assert list(R.blueprint_tabs(path)) == ["overview", "8point", "mine", "probe"]
    image_views = _image_views(bp)
    assert image_views
    for p in pairs:
        w, h = images_extent(p.size_a, p.size_b)
        for b in image_views:
            assert b["x_range"][1] >= w - 0.5 and b["y_range"][1] >= h - 0.5, (p.size_a, b)
    app_id, rebuilt = recording_blueprint(path, active="mine")
    rebuilt.save(app_id, str(tmp_path / "tab.rbl"))
    again = _last_blueprint(tmp_path / "tab.rbl")
    assert again["timeline"] == [[L.TIMELINE]] and "class_ids" not in again  # no override: every F has its keypoints
    assert sorted(map(str, _image_views(again))) == sorted(map(str, image_views))


def test_a_single_pair_still_opens_on_its_probe(logged, tmp_path):
    path = tmp_path / "one.rrd"
    _, pairs, results = logged
    rec = rr.RecordingStream("one")
    rec.save(str(path))
    fviz.log_result(rec, pairs[1], results[1], lines=5, probe=2)
    rec.flush()
    rec.disconnect()
    assert _last_blueprint(path)["timeline"] == [[L.PROBE_TIMELINE]]


def test_at_each_pair_only_its_own_entities_are_live(logged):
    """(b) nothing of an earlier pair lingers: every entity shown at pair i was logged at i (pair 0's own F "mine"
    is cleared from pair 1 on); each F's keypoints at i are pair i's matches."""
    path, pairs, results = logged
    rows = _rows(path)
    assert L.est("a", "mine", "epilines") in _live(rows, 0)
    for i in range(N_PAIRS):
        live = _live(rows, i)
        stale = {e: t for e, t in live.items() if t != i}
        assert not stale, f"pair {i} shows entities of other pairs: {stale}"
        assert L.image("a") in live and L.matches("gt") in live
        assert (L.est("a", "mine", "epilines") in live) == (i == 0)
    for i, r in enumerate(results):  # each F's own keypoints (a single pair's file shows them by a blueprint override)
        times = R.column(path, L.matches("8point"), "pair")
        xy = R.column(path, L.matches("8point"), "Points2D:positions")[times.index(i)]
        assert len(xy) == 2 * r.n_matches
        assert np.allclose(np.asarray(xy, float)[: r.n_matches], r.matches.x_a, atol=1e-3)


def test_pairs_logged_out_of_order_or_again_keep_to_their_own(logged, tmp_path):
    """A pair logged at 7, then one with an F of its own ("mine") at 5: mine is cleared at 7 too; index 5 logged
    again with a pair without mine: gone from 5 as well."""
    path = tmp_path / "order.rrd"
    _, pairs, results = logged
    rec = rr.RecordingStream("order")
    rec.save(str(path))
    for i, k in ((7, 1), (5, 0)):
        fviz.log_result(rec, pairs[k], results[k], index=i, lines=5, probe=2)
    rec.flush()
    rows = _rows(path)
    assert L.est("a", "mine", "epilines") in _live(rows, 5) and L.est("a", "mine", "epilines") not in _live(rows, 7)
    assert not {e: t for e, t in _live(rows, 7).items() if t != 7}
    fviz.log_result(rec, pairs[2], results[2], index=5, lines=5, probe=2)
    rec.flush()
    rec.disconnect()
    rows = _rows(path)
    assert L.est("a", "mine", "epilines") not in _live(rows, 5)
    assert not {e: t for e, t in _live(rows, 5).items() if t != 5}


def _fs(results, i):
    return {e.name: e.F / np.linalg.norm(e.F) for e in results[i].estimators if not e.error and e.F is not None}


def _on_line(seg, F, x) -> bool:
    """Both ends of a segment on OpenCV's epipolar line of x (image a) in image b."""
    line = cv2.computeCorrespondEpilines(np.asarray(x, np.float32).reshape(1, 1, 2), 1, F).reshape(3)
    ends = np.c_[np.asarray(seg, float), np.ones(len(seg))]
    return bool(np.abs(ends @ line / np.hypot(*line[:2])).max() < 1e-2)


def test_each_index_has_its_own_fs_and_a_click_at_the_cursor_gets_that_pairs_lines(logged):
    """(c) click_pairs: pair i's F's and sizes at index i; the page's server (its ClickApp, no browser), the time
    cursor moved to each pair: the click's lines in b are pair i's (OpenCV's F x_a), logged at pair = i."""
    from test_interactive import _selection

    from fviz.web.server import ClickApp

    path, pairs, results = logged
    cp = click_pairs(path)
    assert sorted(cp) == list(range(N_PAIRS))
    for i, p in enumerate(pairs):
        fs = cp[i]
        assert (fs.size_a, fs.size_b) == (tuple(p.size_a), tuple(p.size_b))
        want = _fs(results, i)
        assert fs.names == list(want)
        for name, F in zip(fs.names, fs.F):
            assert np.allclose(F / np.linalg.norm(F), want[name], atol=1e-9), (i, name)
    app = ClickApp(path)
    _, answer = app.new_connection()
    for i in (N_PAIRS - 1, 1, 2):  # the last pair first: a click is never answered with pair 0's lines
        answer(json.dumps({"type": "timeline_change", "application_id": "my-eval", "recording_id": "r",
                           "timeline": L.TIMELINE, "time": float(i)}))
        x = np.array(pairs[i].size_a, float) * [0.3, 0.6]
        (data, *_) = answer(_selection("/a/image", [*x, None])) or [b""]
        assert data, f"pair {i}: no answer"
        f = path.parent / f"answer{i}.rrd"
        f.write_bytes(data)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            (rb,) = [rb for ch in RrdReader(f).stream().to_chunks() if ch.entity_path.strip("/") == "b/click"
                     and "LineStrips2D:strips" in (rb := ch.to_record_batch()).schema.names]  # not the next pair's Clear
        assert rb.column(L.TIMELINE).to_pylist()[0] == i
        strips = rb.column("LineStrips2D:strips").to_pylist()[0]
        snapped = cp[i].x_a[np.argmin(np.linalg.norm(cp[i].x_a - x, axis=1))]
        x = snapped if np.linalg.norm(snapped - x) <= SNAP_PX * screen_unit(cp[i].size_a) else x
        for name, F in _fs(results, i).items():
            assert any(_on_line(s, F, x) for s in strips if len(s) == 2), (i, name)
        other = _fs(results, (i + 1) % N_PAIRS)["8point"]  # and not another pair's
        assert not any(_on_line(s, other, x) for s in strips if len(s) == 2)


def test_bad_index_is_refused(logged):
    _, pairs, results = logged
    with pytest.raises(FvizError, match="index"):
        fviz.log_result(rr.RecordingStream("x"), pairs[0], results[0], index=-1)


def test_the_notebook_viewer_fills_the_cell_and_clicks_from_python(logged):
    """fviz.notebook.show's widget is as wide as the cell (rerun-notebook's "auto": 100 % of the cell, 16:9), not
    a fixed size; ClickViewer.click on a pixel of image b draws its lines in image a where OpenCV puts them (F^T x_b)."""
    import fviz.notebook

    _, pairs, results = logged
    v = fviz.notebook.show(pairs[1], results[1])
    widget = v.viewer._viewer  # the anywidget whose traits the frontend sizes the viewer by
    assert (widget._width, widget._height) == ("auto", "auto")
    x = np.array([200.0, 100.0])
    c = v.click("b", *x)
    assert c is not None and c.view == "b" and v.last is c
    x = c.point  # snapped to a match end when one is within reach
    for name, F in _fs(results, 1).items():
        k = c.names.index(name)
        line = cv2.computeCorrespondEpilines(np.float32(x).reshape(1, 1, 2), 2, F).reshape(3)
        ends = np.c_[c.segments[k], np.ones(2)]
        assert c.inside[k] and np.abs(ends @ line / np.hypot(*line[:2])).max() < 1e-2, name
    assert v.click("a", -50.0, 10.0) is None  # off the image


@pytest.mark.browser
@pytest.mark.slow
def test_the_page_at_the_last_pair_shows_that_pair_alone(logged, tmp_path):
    """``fviz open FILE --web`` in headless Chromium (one page load): the viewer opens on ``pair``; Right (Rerun's
    "step time forward") moves the time cursor pair by pair to the last, and the viewer tells the page so (the time
    it sends, which the page's clicks follow); the tab of pair 0's own F ("mine") then shows the last pair's small images and the ground
    truth's white lines, with no line in mine's colour: nothing of pair 0 lingers (pixels)."""
    import time

    from test_web_viewer import Shot, budget, find_image, near, to_gray, viewer_rendered

    path, pairs, _ = logged
    last = N_PAIRS - 1
    shot = Shot(path, tmp_path / "open.png", keep_open=True)
    with shot:
        b = shot.browser
        events = lambda: [json.loads(e) for e in b.evaluate("window.fviz.events") or []]  # noqa: E731
        assert [e for e in events() if e["type"] == "timeline_change"][-1]["timeline"] == L.TIMELINE  # as eval's
        at = lambda: ([e["time"] for e in events() if e.get("time") is not None] or [None])[-1]  # noqa: E731
        b.click((400, 82), hover=0.3)  # the verdict's text (no image, no time strip): the viewer's canvas takes the keys
        end = time.monotonic() + budget()
        while at() != float(last):  # Right: Rerun's "step time forward", to the next pair (a slow frame may drop one)
            assert time.monotonic() < end, f"the viewer never reported pair {last}: {events()}"
            seen = len(events())
            for kind in ("rawKeyDown", "keyUp"):
                b.call("Input.dispatchKeyEvent", {"type": kind, "key": "ArrowRight", "code": "ArrowRight",
                                                  "windowsVirtualKeyCode": 39, "nativeVirtualKeyCode": 39})
            wait = time.monotonic() + 20
            while len(events()) == seen and time.monotonic() < wait:
                time.sleep(0.5)
        shot.open_tab("mine", tmp_path / "mine.png")
        rgb = shot.rgb
    assert viewer_rendered(rgb)
    frame = to_gray(pairs[last].image_a)
    score, scale, (x, y, w, h) = find_image(to_gray(rgb), frame)
    print(f"pair {last}'s image a at ({x}, {y}) {w}x{h}, scale {scale:.2f}, score {score:.2f}")
    assert score > 0.5, f"the last pair's image a is not on the screen (score {score:.2f}); {shot.context}"
    _, bottom = images_extent(pairs[last].size_a, pairs[last].size_b)
    images = rgb[y: y + int(bottom * scale), x: x + w]
    colors = L.estimator_colors(["gt", "8point", "mine"])
    white, mine = int(near(images, colors["gt"], 40).sum()), int(near(images, colors["mine"]).sum())
    print(f"over the images: {white} white pixels (the ground truth's lines), {mine} in mine's colour")
    assert white > 200, f"no ground truth lines: the tab is not drawn over the last pair; {shot.context}"
    assert mine < 20, f"{mine} pixels in mine's colour: pair 0's lines linger over pair {last}; {shot.context}"
