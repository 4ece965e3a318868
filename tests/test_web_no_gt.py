"""The no-ground-truth screen in a real browser (as tests/test_web_viewer.py): two KITTI frames given as plain
images (``--image-a`` / ``--image-b``, no K, no pose), so fviz knows no ground truth. A person checks that both
frames are there with the estimators' lines over them (the reference estimator's colour), that no white
ground-truth line is drawn anywhere on them, that the comparison chart has a bar per estimator and none for a
ground truth, that its agreement matrix is green where two estimators agree and red where not, that the summary
says which agree, and that the view says "no ground truth". Screenshots are saved under the test's tmp dir."""

from __future__ import annotations

import json

import numpy as np
import pytest
from browser import run_fviz
from test_web_viewer import Shot, near, overlay, to_gray

from fviz.record import layout as L

pytestmark = [pytest.mark.browser, pytest.mark.kitti, pytest.mark.slow]

FRAMES = (3, 4)
ESTIMATORS = ("8point", "ransac", "magsac")  # inspect's defaults; the overview shows the last one's lines
COLORS = L.estimator_colors(list(ESTIMATORS))
WHITE = L.estimator_colors(["gt", *ESTIMATORS])["gt"]


def longest_run(mask: np.ndarray) -> int:
    """The longest horizontal run of True in a (H, W) mask."""
    best = 0
    for row in mask.astype(np.int8):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], row, [0]])))
        if len(edges):
            best = max(best, int((edges[1::2] - edges[::2]).max()))
    return best


@pytest.fixture(scope="module")
def no_gt(kitti_root, tmp_path_factory):
    """(recording, --json, frames) of the pair 3 -> 4 of odometry 00 as two plain images."""
    seq = kitti_root / "odometry" / "dataset" / "sequences" / "00" / "image_0"
    paths = [seq / f"{f:06d}.png" for f in FRAMES]
    out = tmp_path_factory.mktemp("web-no-gt") / "pair.rrd"
    r = run_fviz("inspect", "pair", "--image-a", paths[0], "--image-b", paths[1], "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    import cv2

    frames = {v: to_gray(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)) for v, p in zip("ab", paths)}
    return out, json.loads(r.stdout), frames


def test_no_ground_truth_overview_shows_the_estimators_and_no_ground_truth(no_gt, tmp_path):
    from fviz.record.reader import _blueprint_fields, blueprint_tabs, open_rrd, text

    recording, doc, frames = no_gt
    assert doc["F_gt"] is None and [e["name"] for e in doc["estimators"]] == list(ESTIMATORS)
    shot = Shot(recording, tmp_path / "no-gt-overview.png")
    boxes = shot.frames(frames, (0.0, 0.72))
    ref = ESTIMATORS[-1]
    for v, box in boxes.items():
        crop, drawn = overlay(shot.rgb, frames[v], box)
        crop, drawn = crop[4:-4, 4:-4], drawn[4:-4, 4:-4]  # the frame's inside (its border meets the white UI)
        counts = {n: int((near(crop, c) & drawn).sum()) for n, c in COLORS.items()}
        white = int((near(crop, WHITE, 30) & drawn).sum())
        print(f"image {v}: overlay pixels per colour {counts}, white {white}")
        assert counts[ref] > 1000, f"{ref}'s lines are not drawn on image {v}: {counts}; {shot.context}"
        # an epipole's glyph alone is ~90 px of its colour (its name is black on a box); none drawn is < 10
        assert min(counts.values()) > 40, f"an estimator's epipole is not drawn on image {v}: {counts}; {shot.context}"
        assert white < 100, f"white (ground-truth) lines on image {v}: {white} px; {shot.context}"
    # the comparison chart (right column, its dark background): bars are long runs of one colour, text short
    h, w = shot.rgb.shape[:2]
    chart = shot.rgb[int(0.1 * h): int(0.55 * h), int(0.73 * w):]
    runs = {n: longest_run(near(chart, c, 30)) for n, c in {**COLORS, "white": WHITE}.items()}
    print(f"comparison chart: longest horizontal run per colour {runs}")
    for name in ESTIMATORS[1:]:  # 8point's bar sits under each metric's header label (tinted): not measured
        assert runs[name] > 40, f"no {name} bar in the comparison chart: {runs}; {shot.context}"
    assert runs["white"] < 20, f"a white (ground-truth) bar in the comparison chart: {runs}; {shot.context}"
    # screens round two §5: the agreement matrix, a cell per two estimators, green where their NSGD < 0.05, red
    # where not; the areas of the two colours follow the numbers of agreeing and differing cells of the JSON's matrix
    M = np.array(doc["agreement"]["matrix"])
    off = ~np.eye(len(M), dtype=bool)
    agree, differ = int((off & (M < 0.05)).sum()), int((off & (M >= 0.05)).sum())
    green, red = (int(near(chart, c, 30).sum()) for c in (L.AGREE_COLOR, L.DIFFER_COLOR))
    print(f"agreement matrix: {agree} agreeing and {differ} differing cells; green {green} px, red {red} px")
    assert (green > 300) == (agree > 0) and (red > 300) == (differ > 0), f"{green=} {red=}; {shot.context}"
    if agree and differ:
        assert 0.4 < (green / red) / (agree / differ) < 2.5, f"{green=} {red=} for {agree}:{differ}; {shot.context}"
    # the summary beside it says which agree, with the number behind it (from the JSON's matrix, here)
    summary = text(recording, L.SUMMARY)[0]
    for i, j in zip(*np.triu_indices(len(M), 1)):
        a, b = ESTIMATORS[i], ESTIMATORS[j]
        if M[i, j] < 0.05 and len(M) == 3:
            assert f"{a} and {b} agree (NSGD {M[i, j]:.2g})" in summary, summary[:400]
    assert agree or "no two estimators agree" in summary, summary[:400]
    for k, name in enumerate(ESTIMATORS):
        if agree and (M[k][off[k]] >= 0.05).all():
            assert f"{name} differs (NSGD >= {M[k][off[k]].min():.2g} to each other F)" in summary, summary[:400]
    # the title the screen shows above the images: the notice (rendered text is not OCR'd: read from the file)
    titles = list(blueprint_tabs(recording))
    assert titles[0] == "overview", titles
    names = [(f.get("display_name") or [""])[0] for f in _blueprint_fields(open_rrd(recording)).values()]
    assert any(n.startswith(f"no ground truth: {ref}'s residuals") for n in names), names
