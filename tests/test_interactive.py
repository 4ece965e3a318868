"""Click a point, see its lines (fviz.interactive): the lines of a clicked pixel under every F against OpenCV's
``computeCorrespondEpilines``, the residuals against point-to-line distances computed here, and the click
logged into a recording and read back (a second click replaces the first)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fviz.interactive import PairFs, click, click_at, locate, session_for
from fviz.record import layout as L

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
    off = L.offset_b(SIZE_A)
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
    off = L.offset_b(SIZE_A)
    c = click_at(pair, pair.x_b[j] + off + [2.0, -1.5])  # root frame, 2.5 px from match 7's end in b
    assert c.view == "b" and c.match == j and np.allclose(c.point, pair.x_b[j]) and np.allclose(c.partner, pair.x_a[j])
    for k, F in enumerate(pair.F):
        la = _cv_lines(F, pair.x_b[j], 2)  # in a
        lb = _cv_lines(F, pair.x_a[j], 1)  # in b
        d_a = abs(la @ [*pair.x_a[j], 1]) / np.hypot(*la[:2])
        d_b = abs(lb @ [*pair.x_b[j], 1]) / np.hypot(*lb[:2])
        assert c.residuals[k] == pytest.approx((d_a + d_b) / 2, rel=1e-6)
        assert _same_line(c.lines[k], la)


def test_a_selected_keypoint_instance_wins_over_the_position(pair):
    n = len(pair.x_a)
    c = click_at(pair, [1.0, 1.0], "est/gt/matches", n + 3)  # b's end of match 3
    assert (c.view, c.match) == ("b", 3) and np.allclose(c.point, pair.x_b[3])
    assert click_at(pair, [1.0, 1.0], "a/image", 3).match != 3 or np.linalg.norm(pair.x_a[3] - 1) < 6


def test_a_click_far_from_every_keypoint_has_no_match(pair):
    far = np.array([SIZE_A[0] + 100.0, 0.0])
    c = click(pair, "a", [0.0, 0.0])
    d = np.linalg.norm(pair.x_a - [0.0, 0.0], axis=1).min()
    assert (c.match is None) == (d > 6.0) and np.isnan(c.residuals).all() == (c.match is None)
    assert click_at(pair, far) is None
