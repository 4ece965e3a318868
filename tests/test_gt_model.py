"""Ground-truth correspondences (--gt-matches): the authors' model F read when it lies beside them (in either
convention), otherwise F fitted on their Sampson distance (not the 8-point's algebraic error), and labelled points
on one plane called degenerate. Real fountain-P11 views and the published cameras."""

from __future__ import annotations

import numpy as np
import poselib
import pytest
from sources_util import closed_form_F, same_up_to_sign, strecha_camera, strecha_projection

from fviz.data.correspondences import Correspondences, fit_gt, refined_fit
from fviz.geometry import normalize, sampson_distance, symmetric_epipolar_distance

F_PUB = closed_form_F(strecha_projection("0000.jpg"), strecha_projection("0001.jpg"))


def labelled(n: int = 40, noise: float = 1.5, planar: bool = False, seed: int = 0):
    """Points of the scene seen by the published cameras 0000 and 0001, with hand-labelling noise (px)."""
    rng = np.random.default_rng(seed)
    P_a, P_b = strecha_projection("0000.jpg"), strecha_projection("0001.jpg")
    _, R, C = strecha_camera("0000.jpg")  # camera -> world
    X_cam = rng.uniform([-3, -2, 6], [3, 2, 12], size=(n, 3))  # in front of camera a
    if planar:
        X_cam[:, 2] = 9.0  # one fronto-parallel plane
    X = X_cam @ R.T + C
    proj = lambda P: (np.c_[X, np.ones(n)] @ P.T)[:, :2] / (np.c_[X, np.ones(n)] @ P.T)[:, 2:]  # noqa: E731
    return proj(P_a) + rng.normal(0, noise, (n, 2)), proj(P_b) + rng.normal(0, noise, (n, 2))


def test_the_authors_model_f_is_read_in_either_convention(tmp_path):
    x_a, x_b = labelled()
    np.savetxt(tmp_path / "fountain_pts.txt", np.c_[x_a, x_b])
    for F_file, transposed in ((F_PUB, False), (F_PUB.T, True)):
        np.savetxt(tmp_path / "fountain_model.txt", F_file * 1e3)  # any scale
        F, med, note = fit_gt(Correspondences(x_a, x_b, path=str(tmp_path / "fountain_pts.txt")), None)
        assert same_up_to_sign(F, normalize(F_PUB, "fbn"), 1e-9)
        assert ("transposed" in note) == transposed and "the authors' model F of" in note
        assert med == pytest.approx(np.median(symmetric_epipolar_distance(F_PUB, x_a, x_b)))


def test_without_a_model_the_fit_minimises_sampson_as_poselib_does():
    x_a, x_b = labelled(noise=2.0, seed=1)
    x_a[:3] += 25.0  # three mislabelled points
    import cv2

    F8, _ = cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)
    F = refined_fit(x_a, x_b)
    Fp, _ = poselib.estimate_fundamental(x_a, x_b, {"max_epipolar_error": 4.0}, {})
    ours, eight, theirs = (np.median(sampson_distance(G, x_a, x_b)) for G in (F, F8, Fp))
    assert ours < 0.5 * eight and ours <= 1.1 * theirs  # far better than 8-point, as good as PoseLib's RANSAC + LO
    F_gt, med, note = fit_gt(Correspondences(x_a, x_b, path="labels.txt"), None)
    assert "refined on their Sampson distance" in note and "degenerate" not in note
    assert med == pytest.approx(np.median(symmetric_epipolar_distance(F_gt, x_a, x_b)))


def test_labelled_points_on_one_plane_are_called_degenerate():
    x_a, x_b = labelled(planar=True, noise=0.3, seed=2)
    _, _, note = fit_gt(Correspondences(x_a, x_b, path="plane.txt"), None)
    assert "degenerate: one homography explains" in note
