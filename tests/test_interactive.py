"""Click a point, see its lines (fviz.interactive): the lines of a clicked pixel under every F against OpenCV's
``computeCorrespondEpilines``, the residuals against point-to-line distances computed here, and the click
logged into a recording and read back (a second click replaces the first)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fviz.interactive import PairFs, click, click_at, locate
from fviz.record import layout as L
from fviz.record.placement import offset_b

SIZE_A, SIZE_B = (640, 200), (500, 300)


def _f(rng) -> np.ndarray:
    """An F of a random camera pair: K^-T [t]x R K^-1 (independent of fviz.geometry)."""
    K = np.array([[500.0, 0, 320], [0, 500, 100], [0, 0, 1]])
    w = rng.normal(size=3) * 0.1
    R, _ = cv2.Rodrigues(w)
    t = rng.normal(size=3)
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Ki = np.linalg.inv(K)
    return Ki.T @ tx @ R @ Ki


@pytest.fixture
def pair():
    rng = np.random.default_rng(3)
    Fs = np.stack([_f(rng) for _ in range(3)])
    x_a = rng.uniform([0, 0], [SIZE_A[0] - 1, SIZE_A[1] - 1], (40, 2))
    x_b = rng.uniform([0, 0], [SIZE_B[0] - 1, SIZE_B[1] - 1], (40, 2))
    return PairFs(["gt", "ransac", "magsac"], Fs, SIZE_A, SIZE_B, x_a, x_b)


def _cv_lines(F, pt, which):
    return cv2.computeCorrespondEpilines(np.asarray(pt, np.float32).reshape(1, 1, 2), which, F).reshape(3)


def _same_line(l1, l2):
    l1, l2 = np.asarray(l1, float), np.asarray(l2, float)
    l1, l2 = l1 / np.linalg.norm(l1[:2]), l2 / np.linalg.norm(l2[:2])
    return np.allclose(l1, l2, atol=1e-5) or np.allclose(l1, -l2, atol=1e-5)


def test_locate_tells_the_images_apart_and_undoes_b_shift():
    off = offset_b(SIZE_A)
    assert locate([10, 20, 0], SIZE_A, SIZE_B)[0] == "a"
    view, p = locate([10 + 0, 20 + off[1]], SIZE_A, SIZE_B)
    assert view == "b" and np.allclose(p, [10, 20])
    assert locate([10, SIZE_A[1] + 2], SIZE_A, SIZE_B) is None  # the gap
    assert locate([600, off[1] + 10], SIZE_A, SIZE_B) is None  # right of b (narrower)


@pytest.mark.parametrize("view", ["a", "b"])
def test_a_pixel_lines_equal_opencv(pair, view):
    pt = np.array([123.0, 77.0])
    c = click(pair, view, pt, snap=False)
    assert c.view == view and c.match is None and np.allclose(c.point, pt)
    for k, F in enumerate(pair.F):
        # OpenCV: whichImage 1 -> lines in the second image (F x), 2 -> in the first (F^T x)
        assert _same_line(c.lines[k], _cv_lines(F, pt, 1 if view == "a" else 2))
    # the clipped segments lie on the lines, inside the other image
    other = SIZE_B if view == "a" else SIZE_A
    for k in np.flatnonzero(c.inside):
        ends = np.c_[c.segments[k], np.ones(2)]
        assert np.abs(ends @ c.lines[k]).max() < 1e-6
        assert (ends[:, 0] >= -0.51).all() and (ends[:, 0] <= other[0] - 0.49).all()


def test_a_click_near_a_keypoint_picks_its_match_and_its_residuals(pair):
    j = 7
    off = offset_b(SIZE_A)
    c = click_at(pair, pair.x_b[j] + off + [2.0, -1.5])  # root frame, 2.5 px from match 7's end in b
    assert c.view == "b" and c.match == j and np.allclose(c.point, pair.x_b[j]) and np.allclose(c.partner, pair.x_a[j])
    for k, F in enumerate(pair.F):
        la = _cv_lines(F, pair.x_b[j], 2)  # in a
        lb = _cv_lines(F, pair.x_a[j], 1)  # in b
        d_a = abs(la @ [*pair.x_a[j], 1]) / np.hypot(*la[:2])
        d_b = abs(lb @ [*pair.x_b[j], 1]) / np.hypot(*lb[:2])
        assert c.residuals[k] == pytest.approx((d_a + d_b) / 2, rel=1e-6)
        assert _same_line(c.lines[k], la)


def test_a_selected_keypoint_is_taken_unless_the_position_says_otherwise(pair):
    """Rerun 0.41 reports the entity hovered in the previous frame with the position of the click: a stale
    instance far from the position is ignored."""
    n = len(pair.x_a)
    off = offset_b(SIZE_A)
    c = click_at(pair, None, "est/gt/matches", n + 3)  # b's end of match 3, no position
    assert (c.view, c.match) == ("b", 3) and np.allclose(c.point, pair.x_b[3])
    c = click_at(pair, pair.x_b[3] + off + [1.0, 0.0], "est/gt/matches", n + 3)
    assert (c.view, c.match) == ("b", 3)
    far = np.array([5.0, 5.0]) if np.linalg.norm(pair.x_a[3] - [5.0, 5.0]) > 50 else np.array([600.0, 190.0])
    c = click_at(pair, far, "est/gt/matches", 3)  # stale: the click is far from match 3
    assert c.view == "a" and c.match != 3 and (c.match is not None or np.allclose(c.point, far))


def test_a_click_far_from_every_keypoint_has_no_match(pair):
    far = np.array([SIZE_A[0] + 100.0, 0.0])
    c = click(pair, "a", [0.0, 0.0])
    d = np.linalg.norm(pair.x_a - [0.0, 0.0], axis=1).min()
    assert (c.match is None) == (d > 6.0) and np.isnan(c.residuals).all() == (c.match is None)
    assert click_at(pair, far) is None


# ------------------------------------------------------------------------- the notebook viewer, headless

def _selection(path: str, position=None, instance=None) -> str:
    """The JSON string the notebook widget sends for a click (``rerun._event`` parses it)."""
    import json

    item = {"type": "entity", "entity_path": path, "view_name": "overview"}
    if position is not None:
        item["position"] = [None if v is None else float(v) for v in position]  # Rerun: [x, y, null] in 2D
    if instance is not None:
        item["instance_id"] = instance
    return json.dumps({"type": "selection_change", "application_id": "fviz-notebook", "recording_id": "r", "items": [item]})


def _sent_chunks(viewer, tmp_path):
    """What the widget was sent (queued: no frontend), read back as a recording: {entity: [record batches]}."""
    from rerun.chunk import RrdReader

    import warnings

    blobs = [b for content, buffers in viewer._viewer._event_queue if content.get("type") == "rrd" for b in buffers]
    out: dict[str, list] = {}
    for k, blob in enumerate(blobs):  # each flush is a stream of its own (header first)
        f = tmp_path / f"sent{k}.rrd"
        f.write_bytes(bytes(blob))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = RrdReader(f)
            if not r.recordings():  # the blueprint's
                continue
            for ch in r.stream().to_chunks():
                out.setdefault(ch.entity_path.strip("/"), []).append(ch.to_record_batch())
    return out


@pytest.fixture(scope="module")
def evaluated(odometry):
    from fviz.estimators.registry import get_estimator
    from fviz.evaluate import evaluate_pair

    pair = odometry.pair(3, "temporal")
    names = ("8point", "ransac", "magsac", "lmeds", "7point")
    return pair, evaluate_pair(pair, [(n, get_estimator(n)) for n in names])


@pytest.mark.kitti
def test_notebook_click_draws_the_lines_in_the_other_image(evaluated, tmp_path):
    """fviz.notebook.show on a KITTI pair; a synthetic click (the widget's JSON) on a keypoint of image a:
    the bytes sent to the widget hold b/click with one line per F on F x_a, in the F's colour, and the
    partner's ring; a second click on a plain pixel of b replaces it."""
    import fviz.notebook

    pair, result = evaluated
    v = fviz.notebook.show(pair, result)
    m = result.matches
    j = int(np.argmax(m.x_a[:, 0] > 300))
    c = v.handle(_selection("/a/image", [*(m.x_a[j] + [1.0, 1.0]), 0.0]))  # beside the keypoint
    assert c is not None and c.view == "a" and c.match == j
    v.viewer._viewer._raw_event_callbacks[0](_selection("/a/image", [*(m.x_a[j] + [1.0, 1.0]), 0.0]))  # as the widget does
    sent = _sent_chunks(v.viewer, tmp_path)
    assert "b/click" in sent and "a/click" in sent and "click/text" in sent
    rb = sent["b/click"][-1]
    strips = rb.column("LineStrips2D:strips").to_pylist()[-1]
    colors = rb.column("LineStrips2D:colors").to_pylist()[-1]
    ok = [r for r in result.estimators if not r.error]
    colours = L.estimator_colors([r.name for r in result.estimators])
    drawn = 0
    for r in ok:
        line = _cv_lines(r.F, m.x_a[j], 1)
        want = int.from_bytes(bytes([*colours[r.name], 255]), "big")
        on = [np.asarray(s, float) for s, col in zip(strips, colors) if col == want and len(s) == 2]
        assert on, f"{r.name}: no line in its colour"
        ends = np.c_[on[0], np.ones(2)]
        assert np.abs(ends @ line / np.hypot(*line[:2])).max() < 1e-2, r.name
        drawn += 1
    assert drawn == len(ok) >= 5
    # the partner's ring sits around x_b
    ring = np.asarray(strips[-1], float)
    assert np.allclose(ring.mean(axis=0), m.x_b[j], atol=0.6)
    # a second click, on a plain pixel of b, replaces it: lines now in a, none left in b
    pb = np.array([200.0, 100.0])
    far = np.linalg.norm(m.x_b - pb, axis=1).min() > 10
    c2 = v.handle(_selection("/b/image", [*(pb + offset_b(pair.size_a)), 0.0]))
    assert c2.view == "b" and (c2.match is None) == far
    sent = _sent_chunks(v.viewer, tmp_path)
    last_b = sent["b/click"][-1].column("LineStrips2D:strips").to_pylist()[-1]
    assert len(last_b) == 1  # only the clicked point's ring
    last_a = sent["a/click"][-1].column("LineStrips2D:strips").to_pylist()[-1]
    assert len(last_a) >= len(ok) - 1 + (0 if far else 1)


# ------------------------------------------------------------------------- the page's WebSocket, no browser

def test_the_page_socket_sends_the_recording_and_answers_a_click_with_its_lines(tmp_path):
    """What the browser page does, spoken by a plain WebSocket client: the recording's bytes first; a
    selection's JSON in, the click's bytes out (b/click: one line per F through F x_a); a non-click event
    (time) gets no answer, and the page itself and the viewer's files are served over HTTP, all on one port.
    (What the server refuses: tests/test_web_server.py.)"""
    import json
    import urllib.request
    import warnings

    import websocket
    from browser import free_port, run_fviz
    from rerun.chunk import RrdReader

    from fviz.web.server import PageServer

    rec = tmp_path / "p.rrd"
    r = run_fviz("inspect", "pair", "--synthetic", "--seed", "0", "-e", "8point", "-e", "ransac", "--out", rec, "--json")
    assert r.returncode == 0, r.stderr
    Fs = {e["name"]: np.array(e["F"]) for e in json.loads(r.stdout)["estimators"] if e["F"] is not None}
    port = free_port()
    server = PageServer(rec, "127.0.0.1", port).start()
    try:
        assert server.url == f"http://127.0.0.1:{port}/?token={server.token}"
        page = urllib.request.urlopen(server.url, timeout=10).read().decode()
        assert "/ws?token=" in page and "widget.js" in page
        head = urllib.request.urlopen(f"http://127.0.0.1:{port}/re_viewer_bg.wasm", timeout=10)
        assert head.headers["Content-Type"] == "application/wasm"
        ws = websocket.create_connection(f"ws://127.0.0.1:{port}/ws?token={server.token}", timeout=30,
                                         origin=f"http://127.0.0.1:{port}")
        assert ws.recv() == rec.read_bytes()
        ws.send("ready")
        ws.send(json.dumps({"type": "time_update", "application_id": "x", "recording_id": "y", "time": 0.0}))
        p = np.array([100.0, 80.0])
        ws.send(_selection("/a/image", [*p, 0.0]))
        answer = ws.recv()
        ws.close()
    finally:
        server.close()
    assert isinstance(answer, bytes) and len(server.app.timings) == 1  # the time event was not answered
    f = tmp_path / "answer.rrd"
    f.write_bytes(answer)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        chunks = {ch.entity_path.strip("/"): ch.to_record_batch() for ch in RrdReader(f).stream().to_chunks()}
    strips = chunks["b/click"].column("LineStrips2D:strips").to_pylist()[-1]
    c = server.app.pairs[0]
    x = c.x_a[np.argmin(np.linalg.norm(c.x_a - p, axis=1))] if np.linalg.norm(c.x_a - p, axis=1).min() <= 6 else p
    for name, F in Fs.items():
        line = _cv_lines(F, x, 1)
        assert any(np.abs(np.c_[np.asarray(s, float), np.ones(len(s))] @ line / np.hypot(*line[:2])).max() < 1e-2
                   for s in strips if len(s) == 2), name


def test_on_a_run_the_click_goes_to_the_pair_at_the_time_cursor(pair, tmp_path):
    """Two pairs (indices 4 and 9); the time cursor moves to 9 (TimeUpdateEvent on ``pair``): the click uses
    pair 9's F's and is logged at pair = 9; a cursor between pairs picks the pair before it."""
    import warnings

    import rerun as rr
    from rerun._event import _viewer_event_from_json_str
    from rerun.chunk import RrdReader

    from fviz.interactive import ClickSession

    other = PairFs(pair.names, pair.F[::-1], SIZE_A, SIZE_B, pair.x_a, pair.x_b)
    rec = rr.RecordingStream("fviz-test", recording_id="run")
    stream = rec.binary_stream()
    s = ClickSession(rec, {4: pair, 9: other})
    ev = '{"type": "%s", "application_id": "fviz-test", "recording_id": "run", %s}'
    s.on_event(_viewer_event_from_json_str(ev % ("timeline_change", '"timeline": "pair", "time": 9.0')))
    c = s.on_event(_viewer_event_from_json_str(_selection("/a/image", [50.0, 60.0, None])))
    assert s.index == 9 and _same_line(c.lines[0], _cv_lines(other.F[0], c.point, 1))
    s.on_event(_viewer_event_from_json_str(ev % ("time_update", '"time": 7.0')))
    assert s.index == 4
    f = tmp_path / "run.rrd"
    f.write_bytes(stream.read())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        times = [t for ch in RrdReader(f).stream().to_chunks() if ch.entity_path.strip("/") == "b/click"
                 for t in ch.to_record_batch().column("pair").to_pylist()]
    assert times == [9]


@pytest.mark.kitti
@pytest.mark.slow
def test_the_notebook_path_runs_in_a_real_kernel(kitti_root, tmp_path):
    """A notebook executed headless (nbclient, ipykernel): fviz.notebook.open on an inspected recording shows
    the widget, and the widget's JSON for a click on a keypoint of b, fed as the frontend would, gives the
    click (its match and partner)."""
    import nbformat
    from nbclient import NotebookClient

    from browser import run_fviz

    rec = tmp_path / "p.rrd"
    r = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frame", "3",
                 "-e", "ransac", "--out", rec)
    assert r.returncode == 0, r.stderr
    code = f"""
import json, numpy as np
import fviz.notebook
from fviz.record.placement import offset_b
v = fviz.notebook.open({str(rec)!r})
v
fs = v.session.pairs[0]
p = fs.x_b[10] + offset_b(fs.size_a)
msg = json.dumps({{"type": "selection_change", "application_id": "a", "recording_id": "r",
                  "items": [{{"type": "entity", "entity_path": "/b/image", "position": [float(p[0]), float(p[1]), None]}}]}})
v.viewer._viewer._handle_custom_msg(msg, [])  # what ipywidgets does with the frontend's message
print("CLICK", v.last.view, v.last.match, np.allclose(v.last.partner, fs.x_a[10]))
"""
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(code)])
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    out = "".join(o.get("text", "") for o in nb.cells[0].outputs if o.get("output_type") == "stream")
    assert "CLICK b 10 True" in out, nb.cells[0].outputs
