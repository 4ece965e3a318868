"""Every image shape lays out, read back from real recordings: KITTI's 3.3:1 frames stacked, a 3072x2048
pair, a portrait pair and a 4:3 pair (made from fountain-P11 at test time, shapes_util) side by side; the
numbers and the residual scale below both images inside the view's bounds at the same size on screen;
epipole labels apart; the probe ordered by the estimators' disagreement (never a baseline's residual),
near-duplicates skipped; ``--gt-matches`` drawing and walking the hand-labelled correspondences."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_util import run_fviz
from shapes_util import fountain_args, shaped_pair
from sources_util import FAST

from fviz.record import layout as L
from fviz.record import reader as R
from fviz.record.marks import TAG_CHAR_PX, TAG_ROW_PX
from fviz.record.placement import FOOTER_PX, offset_b, screen_unit, side_by_side

SHAPES = ("3072x2048", "portrait", "4:3")


def inspect(args, out, *extra) -> dict:
    r = run_fviz("inspect", "pair", *args, *FAST, *extra, "--out", out, "--json", timeout=600)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


@pytest.fixture(scope="module")
def shaped(tmp_path_factory):
    """{shape: (recording, its --json)}; the portrait pair with the baseline ``ahead`` among its estimators."""
    out = tmp_path_factory.mktemp("shapes")
    runs = {}
    for shape in SHAPES:
        args = fountain_args() if shape == "3072x2048" else shaped_pair(shape, out / shape.replace(":", ""))
        extra = ("-e", "ahead", "-e", "8point", "-e", "ransac", "-e", "magsac") if shape == "portrait" else ()
        rrd = out / f"{shape.replace(':', '')}.rrd"
        runs[shape] = rrd, inspect(args, rrd, *extra)
    return runs


def caption_and_scale(path, name: str):
    """(the estimator's numbers' anchor, the residual scale's segments) below the images, in the root frame."""
    shift = offset_b(R.image_size(path, "a"))
    strips = R.column(path, L.est("b", name, "epilines"), "LineStrips2D:strips")[0]
    labels = R.column(path, L.est("b", name, "epilines"), "LineStrips2D:labels")[0]
    caption = next(np.array(s[0]) for s, lab in zip(strips, labels) if lab.startswith(f"{name}: SED"))
    gt_strips = R.column(path, L.est("b", "gt", "epilines"), "LineStrips2D:strips")[0]
    gt_labels = R.column(path, L.est("b", "gt", "epilines"), "LineStrips2D:labels")[0]
    scale = [np.array(s) + shift for s, lab in zip(gt_strips, gt_labels) if lab.startswith("keypoint residual")]
    return caption + shift, scale


@pytest.mark.parametrize("shape", SHAPES)
def test_a_pair_of_any_shape_sits_side_by_side_with_its_footer_in_view(shaped, shape):
    path, doc = shaped[shape]
    size = tuple(doc["pair"]["size_a"])
    assert side_by_side(size) and not side_by_side((1241, 376))
    shift = offset_b(size)
    assert shift[1] == 0 and shift[0] > size[0]  # b right of a, apart
    w, h = size[0] + shift[0], size[1]
    unit = screen_unit(size)
    caption, scale = caption_and_scale(path, "ransac")
    assert w / 2 - 1 < caption[0] < w / 2 + 1 and h < caption[1] < h + FOOTER_PX * unit  # centred under both
    ys = {float(s[0][1]) for s in scale}
    xs = np.array([p[0] for s in scale for p in s])
    assert len(scale) == L.RESIDUAL_CLASSES and len(ys) == 1 and caption[1] < ys.pop() < h + FOOTER_PX * unit
    # the scale is as wide on screen whatever the image size: 28 screen px per bin
    assert (xs.max() - xs.min()) / unit == pytest.approx(28.0 * L.RESIDUAL_CLASSES, rel=1e-3)
    assert xs.min() > 0 and xs.max() < w


def label_boxes(path, view: str, unit: float):
    """The overview's epipole name labels as screen-sized boxes (x0, y0, x1, y1) in image px."""
    pts = R.column(path, L.epipoles(view), "Points2D:positions")[0]
    names = R.column(path, L.epipoles(view), "Points2D:labels")[0]
    return [(x - (len(n) + 2) * TAG_CHAR_PX * unit / 2, y, x + (len(n) + 2) * TAG_CHAR_PX * unit / 2, y + TAG_ROW_PX * unit)
            for (x, y), n in zip(pts, names) if not n.startswith(("keypoint residual", ">="))]


def test_epipole_labels_never_overlap(shaped):
    for shape, (path, doc) in shaped.items():
        unit = screen_unit(tuple(doc["pair"]["size_a"]))
        for v in L.VIEWS:
            boxes = label_boxes(path, v, unit)
            assert len(boxes) == len(doc["estimators"]), (shape, v, boxes)
            for i, a in enumerate(boxes):
                for b in boxes[i + 1:]:
                    apart = a[2] <= b[0] + 1e-3 or b[2] <= a[0] + 1e-3 or a[3] <= b[1] + 1e-3 or b[3] <= a[1] + 1e-3
                    assert apart, (shape, v, a, b)


def sed(F, xa, xb) -> float:
    """Symmetric epipolar distance, written out."""
    F = np.asarray(F)
    lb, la = F @ np.append(xa, 1.0), F.T @ np.append(xb, 1.0)
    r = abs(np.append(xb, 1.0) @ lb)
    return 0.5 * (r / np.hypot(*lb[:2]) + r / np.hypot(*la[:2]))


def probe_ends(path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(a's ends, b's ends, texts) of the probe's steps: the centres of the rings."""
    ends = {}
    for v in L.VIEWS:
        strips = R.column(path, L.probe(v), "LineStrips2D:strips", L.PROBE_TIMELINE)
        labels = R.column(path, L.probe(v), "LineStrips2D:labels", L.PROBE_TIMELINE)
        ends[v] = np.array([np.array(next(s for s, lab in zip(ss, ll) if "epipolar line" not in lab))[:-1].mean(0)
                            for ss, ll in zip(strips, labels)])
    return ends["a"], ends["b"], R.text(path, L.PROBE_TEXT)


def test_probe_orders_by_disagreement_never_by_a_baseline(shaped):
    """The portrait pair with ``ahead`` (a constant F, tens of px off everywhere): the probe's order is the
    disagreement of gt, 8point, ransac and magsac, recomputed here from the recorded F's, and ahead's residual
    does not drive it; no two steps ring the same place; the zoom frames follow the match."""
    path, doc = shaped["portrait"]
    Fs = {e["name"]: np.array(e["F"]) for e in doc["estimators"]}
    xa, xb, texts = probe_ends(path)
    assert len(xa) == len(texts) == 20
    assert all("By disagreement of 8point, ransac, magsac, gt" in t for t in texts)
    spread = [max(sed(F, a, b) for n, F in Fs.items() if n != "ahead") - min(sed(F, a, b) for n, F in Fs.items() if n != "ahead")
              for a, b in zip(xa, xb)]
    assert all(p >= q - 1e-3 for p, q in zip(spread, spread[1:])), spread
    ahead = [sed(Fs["ahead"], a, b) for a, b in zip(xa, xb)]
    assert ahead != sorted(ahead, reverse=True)  # not ahead's order
    unit = screen_unit(tuple(doc["pair"]["size_a"]))
    for ends in (xa, xb):
        gaps = np.linalg.norm(ends[:, None] - ends[None], axis=-1) + 1e9 * np.eye(len(ends))
        assert gaps.min() >= 20.0 * unit - 1e-3
    zoom_a = np.array(R.column(path, L.probe_zoom("a"), "Transform3D:translation", L.PROBE_TIMELINE))[:, 0, :2]
    zoom_b = np.array(R.column(path, L.probe_zoom("b"), "Transform3D:translation", L.PROBE_TIMELINE))[:, 0, :2]
    np.testing.assert_allclose(zoom_a, xa, atol=1e-3)
    np.testing.assert_allclose(zoom_b, xb + offset_b(tuple(doc["pair"]["size_a"])), atol=1e-3)
    tabs = R.blueprint_tabs(path)
    assert tabs["probe"].count("+ a/image") == 3  # the whole images and the two zoomed views


def test_gt_matches_are_drawn_and_walked_mislabel_first(shaped, tmp_path):
    """Hand-labelled correspondences (the good matches of the 4:3 pair, one moved 15 px off its line): the
    overview draws all of them, rings the mislabelled one with its residual, and the probe's first step is it."""
    path, doc = shaped["4:3"]
    n = doc["n_matches"]
    pts = np.array(R.column(path, L.matches("gt"), "Points2D:positions")[0])
    xa, xb = pts[:n], pts[n:] - offset_b(tuple(doc["pair"]["size_a"]))
    F = np.array(next(e["F"] for e in doc["estimators"] if e["name"] == "gt"))
    good = [i for i in range(n) if sed(F, xa[i], xb[i]) < 0.5]
    assert len(good) > 100
    rows = np.c_[xa[good], xb[good]]
    lb = F @ np.append(rows[7, :2], 1.0)
    rows[7, 2:] += 15.0 * lb[:2] / np.hypot(*lb[:2])  # across its epipolar line in b
    np.savetxt(tmp_path / "gt.txt", rows, fmt="%.4f")
    args = shaped_pair("4:3", tmp_path / "img")[:6]  # the images and K, no F
    out = tmp_path / "labelled.rrd"
    doc2 = inspect(args, out, "--gt-matches", tmp_path / "gt.txt")
    assert doc2["eval_points"] == "gt-matches"
    drawn = np.array(R.column(out, L.LABELLED, "Points2D:positions")[0])
    np.testing.assert_allclose(drawn[: len(good)], rows[:, :2], atol=1e-3)
    ringed = R.column(out, L.LABELLED, "LineStrips2D:labels")[0]
    assert ringed and all(lab.startswith("labelled correspondence 7: ") for lab in ringed)
    assert f"+ {L.LABELLED}" in R.blueprint_tabs(out)["overview"]
    xa_p, _, texts = probe_ends(out)
    np.testing.assert_allclose(xa_p[0], rows[7, :2], atol=1e-3)
    assert texts[0].startswith("**step 1 of ") and "labelled correspondence 7" in texts[0]
    assert "ground truth's residual: a mislabelled correspondence first" in texts[0]


# ---------------------------------------------------------------------------------------------- in a browser


def frames_of(path) -> dict[str, np.ndarray]:
    """The recorded images, grey, as the viewer decodes them."""
    import cv2

    blobs = {v: R.column(path, L.image(v), "EncodedImage:blob")[0] for v in L.VIEWS}
    return {v: cv2.imdecode(np.asarray(b[0] if isinstance(b[0], list) else b, np.uint8), cv2.IMREAD_GRAYSCALE)
            for v, b in blobs.items()}


def side_by_side_boxes(shot, frames, width: float = 1.0) -> dict[str, tuple[int, int, int, int]]:
    """Image a found in the left half of the first ``width`` of the screen, image b in the right half, at one
    scale, b right of a. -> {view: (x, y, w, h)}."""
    from test_web_viewer import find_image

    grey = shot.rgb.mean(-1).astype(np.uint8)
    half = int(width * grey.shape[1] / 2)
    found = {}
    for v, x0 in (("a", 0), ("b", half)):
        _, scale, _ = find_image(grey[:, x0: x0 + half], frames[v], np.arange(0.1, 1.0, 0.01))
        # a 3072 px photo shows at ~0.19: a step of 0.01 is 5 % of its width; refine to 0.5 %
        score, scale, (x, y, w, h) = find_image(grey[:, x0: x0 + half], frames[v], np.arange(scale - 0.01, scale + 0.01, 0.001))
        print(f"image {v}: correlation {score:.2f} at scale {scale:.2f}, box x={x + x0} y={y} {w}x{h}")
        assert score > 0.45, f"image {v} not found ({score:.2f}); {shot.context}"
        found[v] = (scale, (x + x0, y, w, h))
    assert abs(found["a"][0] - found["b"][0]) < 0.03, f"a and b at different scales; {shot.context}"
    assert found["a"][1][0] + found["a"][1][2] <= found["b"][1][0] + 4, f"b is not right of a; {shot.context}"
    return {v: box for v, (_, box) in found.items()}


@pytest.mark.browser
@pytest.mark.slow
@pytest.mark.parametrize("shape", ["3072x2048", "portrait"])
def test_numbers_and_scale_are_not_occluded(shaped, shape, tmp_path):
    """An estimator's tab of a 3072x2048 and of a portrait pair (:func:`assert_numbers_and_scale_in_view`); on the
    3072 pair, a click on the probe tab then, in the same page (:func:`assert_probe_rings_and_zoomed_ends`). The
    portrait pair opens on the overview, whose images fill the view's height: the residual scale's end labels
    under both whole, then a click on ransac's tab."""
    from test_web_viewer import Shot, assert_scale_end_labels_whole

    path, doc = shaped[shape]
    if shape == "portrait":
        with Shot(path, tmp_path / "portrait-overview.png", keep_open=True) as shot:
            assert_scale_end_labels_whole(shot, side_by_side_boxes(shot, frames_of(path), width=0.72))
            shot.open_tab("ransac", tmp_path / "portrait-ransac.png")
            assert_numbers_and_scale_in_view(shot, path)
        return
    with Shot(path, tmp_path / "3072x2048-ransac.png", "--tab", "ransac", keep_open=True) as shot:
        assert_numbers_and_scale_in_view(shot, path)
        shot.open_tab("probe", tmp_path / "3072-probe.png")
        assert_probe_rings_and_zoomed_ends(shot, path, doc)


def assert_numbers_and_scale_in_view(shot, path) -> None:
    """Both images side by side and large, and below them, inside the view (above the time panel), the numbers
    (a label box, its text in LABEL_OFF_PHOTO) and every bin of the residual scale, clear of the images."""
    from test_web_viewer import LABEL_BOXES, near

    boxes = side_by_side_boxes(shot, frames_of(path))
    assert min(b[2] for b in boxes.values()) > 400, f"images small: {boxes}; {shot.context}"
    x0, x1 = boxes["a"][0], boxes["b"][0] + boxes["b"][2]
    bottom = max(b[1] + b[3] for b in boxes.values())
    # the footer (FOOTER_PX screen px or more below the images) between the images and the time panel (its
    # bottom ~40 px of the window): the numbers (a label box, either theme's, text on it) and the scale's bins
    footer = shot.rgb[bottom + 6: shot.rgb.shape[0] - 40, x0: x1]
    box = int(sum((np.abs(footer.astype(int) - np.array(c)).max(-1) <= 3).sum() for c in LABEL_BOXES))
    text = int(near(footer, L.LABEL_OFF_PHOTO, 40).sum())
    bins = [int(near(footer, c, 25).sum()) for c in L.class_color(np.arange(L.RESIDUAL_CLASSES))]
    print(f"below the images (bottom {bottom}): {box} label-box and {text} text pixels, residual scale pixels per bin {bins}")
    assert box > 2000 and text > 100, f"no numbers below the images ({box} label-box, {text} text pixels); {shot.context}"
    assert all(b > 20 for b in bins), f"residual scale cut or missing: {bins}; {shot.context}"


def assert_probe_rings_and_zoomed_ends(shot, path, doc) -> None:
    """The probe tab of the 3072x2048 pair: the first step's rings (yellow) where the recording puts them on
    both images, and in the two zoomed views the yellow 3 px ring with the F's lines; the photo itself at its
    own grey (the images are not blended with anything)."""
    frames = frames_of(path)
    boxes = side_by_side_boxes(shot, frames, width=0.75)
    xa, xb, _ = probe_ends(path)
    yellow = L.PROBE_COLOR
    for v, at in (("a", xa[0]), ("b", xb[0])):
        x, y, w, h = boxes[v]
        s = w / frames[v].shape[1]
        sx, sy = int(x + (at[0] + 0.5) * s), int(y + (at[1] + 0.5) * s)
        n = shot.count(yellow, (sx - 16, sy - 16, 33, 33))
        print(f"image {v}: ring at screen ({sx}, {sy}): {n} yellow pixels")
        assert n > 30, f"image {v}: the probe's ring is not visible at ({sx}, {sy}); {shot.context}"
    h, w = shot.rgb.shape[:2]
    zoom = (int(0.76 * w), 90, w - int(0.76 * w), int(0.33 * h))
    ring = shot.count(yellow, zoom)
    lines = {n: shot.count(c, zoom) for n, c in L.estimator_colors([e["name"] for e in doc["estimators"]]).items()}
    print(f"zoomed views {zoom}: {ring} yellow ring pixels, line pixels {lines}")
    assert ring > 60 and lines["gt"] > 60, f"zoomed views without the ring or the lines; {shot.context}"
    x, y, bw, bh = boxes["a"]
    crop = shot.rgb[y: y + bh, x: x + bw].mean(-1)
    import cv2

    true = cv2.resize(frames["a"], (bw, bh), interpolation=cv2.INTER_AREA).astype(float)
    for grey in (60, 110, 160):
        at = np.abs(true - grey) < 4
        seen = float(np.median(crop[at]))
        assert abs(seen - grey) < 12, f"the photo's grey {grey} shows as {seen:.0f}; {shot.context}"
