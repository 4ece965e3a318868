import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fviz.geometry import (
    border_point,
    clip_lines,
    describe_epipole,
    epipoles,
    fundamental_from_motion,
    lines_in_a,
    lines_in_b,
)

K = np.array([[718.856, 0, 607.1928], [0, 718.856, 185.2157], [0, 0, 1.0]])
W, H = 1241, 376


def test_epipolar_lines_match_opencv():
    R = cv2.Rodrigues(np.array([0.01, 0.03, 0.0]))[0]
    F = fundamental_from_motion(K, K, R, np.array([0.2, 0.0, 1.0]))
    pts = np.random.default_rng(0).uniform([0, 0], [W, H], (40, 2))
    for ours, which in ((lines_in_b(F, pts), 1), (lines_in_a(F, pts), 2)):
        cv = cv2.computeCorrespondEpilines(pts.reshape(-1, 1, 2), which, F).reshape(-1, 3)
        sign = np.sign(np.sum(ours * cv, axis=1))[:, None]
        np.testing.assert_allclose(ours, sign * cv, atol=1e-6)


def test_epipoles_are_the_projected_camera_centres():
    R = cv2.Rodrigues(np.array([0.02, -0.05, 0.01]))[0]
    t = np.array([0.3, -0.1, 1.0])
    e_a, e_b = epipoles(fundamental_from_motion(K, K, R, t))
    centre_b_in_a = K @ (-R.T @ t)  # camera b's centre seen from a
    centre_a_in_b = K @ t
    assert abs(np.cross(e_a, centre_b_in_a)).max() < 1e-9 * np.linalg.norm(centre_b_in_a)
    assert abs(np.cross(e_b, centre_a_in_b)).max() < 1e-9 * np.linalg.norm(centre_a_in_b)


def test_forward_motion_epipole_is_inside_near_the_principal_point():
    e_a, _ = epipoles(fundamental_from_motion(K, K, np.eye(3), np.array([0.0, 0.0, 1.0])))
    ep = describe_epipole(e_a, W, H)
    assert ep.inside
    np.testing.assert_allclose(ep.point, K[:2, 2], atol=1e-6)


def test_stereo_epipole_is_at_infinity_along_x():
    e_a, _ = epipoles(fundamental_from_motion(K, K, np.eye(3), np.array([-0.54, 0.0, 0.0])))
    ep = describe_epipole(e_a, W, H)
    assert ep.point is None and not ep.inside
    assert abs(ep.direction[0]) == pytest.approx(1.0)
    b = border_point(ep.direction, W, H)
    assert b[0] in (pytest.approx(-0.5), pytest.approx(W - 0.5))


def test_clip_horizontal_line_spans_the_image():
    seg, ok = clip_lines(np.array([[0.0, 1.0, -100.0]]), W, H)
    assert ok[0]
    np.testing.assert_allclose(sorted(seg[0][:, 0]), [-0.5, W - 0.5])
    np.testing.assert_allclose(seg[0][:, 1], [100, 100])


def test_clip_line_missing_the_image_is_invalid():
    seg, ok = clip_lines(np.array([[0.0, 1.0, 1000.0]]), W, H)  # y = -1000
    assert not ok[0] and np.isnan(seg[0]).all()


@given(st.floats(0, W - 1), st.floats(0, H - 1), st.floats(0, np.pi))
def test_clipped_segment_lies_on_the_line_and_ends_on_the_border(x, y, angle):
    n = np.array([np.cos(angle), np.sin(angle)])
    line = np.array([n[0], n[1], -(n @ [x, y])])
    seg, ok = clip_lines(line[None], W, H)
    assert ok[0]
    p, q = seg[0]
    for e in (p, q):
        assert abs(line @ [e[0], e[1], 1.0]) < 1e-6
        on_border = min(abs(e[0] + 0.5), abs(e[0] - (W - 0.5)), abs(e[1] + 0.5), abs(e[1] - (H - 0.5)))
        assert on_border < 1e-6
    # the interior point lies between the two ends
    assert np.linalg.norm(p - [x, y]) + np.linalg.norm(q - [x, y]) == pytest.approx(np.linalg.norm(p - q), rel=1e-6)
