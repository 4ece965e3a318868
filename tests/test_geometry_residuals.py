import cv2
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from fviz.geometry import (
    algebraic,
    fundamental_from_motion,
    sampson_distance,
    symmetric_epipolar_distance,
)

K = np.array([[718.856, 0, 607.1928], [0, 718.856, 185.2157], [0, 0, 1.0]])
R = cv2.Rodrigues(np.array([0.01, 0.04, -0.01]))[0]
F = fundamental_from_motion(K, K, R, np.array([0.1, 0.05, 1.0]))
rng = np.random.default_rng(0)
xa = rng.uniform([0, 0], [1241, 376], (60, 2))
xb = xa + rng.normal(0, 5, (60, 2))


def test_algebraic_is_the_bilinear_form():
    direct = [abs(np.r_[b, 1] @ F @ np.r_[a, 1]) for a, b in zip(xa, xb)]
    np.testing.assert_allclose(algebraic(F, xa, xb), direct, rtol=1e-12)


def test_sampson_matches_opencv():
    cv = [cv2.sampsonDistance(np.r_[a, 1].reshape(3, 1), np.r_[b, 1].reshape(3, 1), F) for a, b in zip(xa, xb)]
    np.testing.assert_allclose(sampson_distance(F, xa, xb) ** 2, cv, rtol=1e-9)


def test_sed_is_the_mean_point_to_line_distance():
    la = np.c_[xb, np.ones(60)] @ F
    lb = np.c_[xa, np.ones(60)] @ F.T
    d_b = np.abs(np.sum(lb * np.c_[xb, np.ones(60)], 1)) / np.hypot(lb[:, 0], lb[:, 1])
    d_a = np.abs(np.sum(la * np.c_[xa, np.ones(60)], 1)) / np.hypot(la[:, 0], la[:, 1])
    np.testing.assert_allclose(symmetric_epipolar_distance(F, xa, xb), (d_a + d_b) / 2, rtol=1e-12)


def test_rectified_stereo_sed_is_the_row_difference():
    Fs = fundamental_from_motion(K, K, np.eye(3), np.array([-0.54, 0, 0]))
    np.testing.assert_allclose(symmetric_epipolar_distance(Fs, xa, xb), np.abs(xa[:, 1] - xb[:, 1]), atol=1e-9)


@given(st.floats(1e-6, 1e6), st.booleans())
def test_distances_do_not_depend_on_the_scale_of_f(s, flip):
    G = (-s if flip else s) * F
    np.testing.assert_allclose(symmetric_epipolar_distance(G, xa, xb), symmetric_epipolar_distance(F, xa, xb), rtol=1e-9)
    np.testing.assert_allclose(sampson_distance(G, xa, xb), sampson_distance(F, xa, xb), rtol=1e-9)
    np.testing.assert_allclose(algebraic(G, xa, xb), s * algebraic(F, xa, xb), rtol=1e-9)
