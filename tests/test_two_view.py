"""Two-view checks as triage tags: COLMAP's configuration label, Bougnoux focals, and whether a failure is
the matcher's or the estimator's, through evaluate_pair -> diagnose -> tag_pair on real and planar pairs."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from fviz.data.pair import Pair, PairId
from fviz.diagnose import diagnose, focal_observable, focals, has_two_view
from fviz.estimators import get_estimator
from fviz.estimators.external import bougnoux_focals
from fviz.estimators.features import detect, match
from fviz.evaluate import evaluate_pair
from fviz.geometry import fundamental_from_motion
from fviz.triage import Ranked, add_two_view, tag_pair

K = np.array([[718.856, 0.0, 607.19], [0.0, 718.856, 185.22], [0.0, 0.0, 1.0]])


def _rotation(deg_xyz) -> np.ndarray:
    return cv2.Rodrigues(np.radians(np.asarray(deg_xyz, float)))[0]


def _pair(image_a, image_b, R, t, points=(None, None)) -> Pair:
    F = fundamental_from_motion(K, K, R, t)
    return Pair(PairId("synthetic", "test", "temporal", 0, 1, 0, 0), image_a, image_b, K, K, R, np.asarray(t, float),
                F / np.linalg.norm(F), 0.0, *points)


@pytest.fixture(scope="module")
def planar(odometry):
    """A real KITTI image and its view from a camera moved 0.6 m sideways in front of a plane 8 m away:
    image b is image a warped by the plane's homography K (R + t n^T / d) K^-1."""
    image = odometry.pair(0, "temporal").image_a
    R, t, n, d = _rotation([0.5, 2.0, 0.0]), np.array([0.6, 0.05, 0.2]), np.array([0.0, 0.0, 1.0]), 8.0
    H = K @ (R + np.outer(t, n) / d) @ np.linalg.inv(K)
    return _pair(image, cv2.warpPerspective(image, H, image.shape[::-1]), R, t)


def _record(pair, names):
    result = evaluate_pair(pair, [(n, get_estimator(n)) for n in names])
    return {"error": None, "result": result.to_dict(), "diagnostics": diagnose(pair, result)}


def test_a_planar_pair_gets_colmaps_planar_tag(planar):
    rec = _record(planar, ["magsac"])
    assert rec["diagnostics"]["two_view"] == "planar"
    assert "colmap-planar" in [t for t, _ in tag_pair(rec, "magsac")]


def test_a_real_temporal_pair_is_calibrated_and_untagged(odometry):
    pair = odometry.pair(3, "temporal")
    rec = _record(pair, ["magsac"])
    assert rec["diagnostics"]["two_view"] == "calibrated"
    tags = [t for t, _ in tag_pair(rec, "magsac")]
    assert not [t for t in tags if t.startswith("colmap-") or t in ("matcher", "estimator", "focal-implausible")]


@pytest.fixture(scope="module")
def general():
    """Exact projections of points in a box seen from two cameras in general position (verging, raised)."""
    rng = np.random.default_rng(1)
    X = rng.uniform([-4, -2, 6], [4, 2, 14], size=(400, 3))
    R, t = _rotation([20.0, -35.0, 10.0]), np.array([5.0, 3.0, 2.0])
    proj = lambda P: (P @ K.T)[:, :2] / P[:, 2:]  # noqa: E731
    blank = np.zeros((376, 1241), np.uint8)
    return _pair(blank, blank, R, t, (proj(X), proj(X @ R.T + t)))


def test_bougnoux_recovers_the_true_focal_in_general_position(general):
    f_a, f_b = bougnoux_focals(general.F_gt, K[:2, 2], K[:2, 2])
    assert f_a == pytest.approx(K[0, 0], rel=1e-6) and f_b == pytest.approx(K[0, 0], rel=1e-6)


def test_focals_are_observable_in_general_position_but_not_on_kitti(general, odometry):
    assert focal_observable(general, general.points_a, general.points_b)
    for pair in (odometry.pair(0, "stereo"), odometry.pair(3, "temporal")):  # parallel axes; forward motion
        m = match(detect(pair.image_a), detect(pair.image_b))
        assert not focal_observable(pair, m.x_a, m.x_b)


def test_an_f_of_the_wrong_focal_is_tagged_focal_implausible(general):
    K_wrong = K.copy()
    K_wrong[0, 0] = K_wrong[1, 1] = 3 * K[0, 0]  # the same principal point, 3 times the focal for image a
    wrong = fundamental_from_motion(K_wrong, K, general.R, general.t)
    assert focals(general, wrong)[0] == pytest.approx(3 * K[0, 0], rel=1e-6)
    for F, tagged in ((wrong, True), (general.F_gt, False)):
        rec = {"error": None, "result": {"pair": general.to_dict(), "estimators": []},
               "diagnostics": {"n_matches": 400, "baseline_m": 1.6, "rotation_fraction": 0.0, "focal_observable": True,
                               "estimators": {"x": {"focals": focals(general, F)}}}}
        assert ("focal-implausible" in [t for t, _ in tag_pair(rec, "x")]) is tagged


def test_a_failing_pair_is_blamed_on_the_estimator_or_the_matcher(odometry):
    """8-point on all matches fails a KITTI temporal pair whose matches are good: the estimator's fault.
    The same pair with image b taken 40 frames later (a matcher that matched the wrong image): the matcher's."""
    pair = odometry.pair(3, "temporal")
    rec = _record(pair, ["8point"])
    assert rec["result"]["match_precision"]["px_prec@2"] > 0.8
    tags = dict(tag_pair(rec, "8point"))
    assert "estimator" in tags and "matcher" not in tags, tags
    wrong = replace(pair, image_b=odometry.pair(43, "temporal").image_a)
    rec = _record(wrong, ["magsac"])
    assert rec["result"]["match_precision"]["px_prec@2"] < 0.5
    tags = dict(tag_pair(rec, "magsac"))
    assert "matcher" in tags and "estimator" not in tags, tags


def test_no_blame_where_the_ground_truth_is_suspect(odometry):
    """Frames 8 -> 9 of sequence 00: KITTI's pose is ~2-3 px off; every tight fit disagrees with it."""
    rec = _record(odometry.pair(8, "temporal"), ["magsac", "8point"])
    tags = dict(tag_pair(rec, "8point"))
    assert "gt-suspect" in tags and not {"matcher", "estimator"} & set(tags), tags


def test_eval_leaves_the_two_view_checks_to_triage_which_tags_the_pairs_it_lists(planar):
    """eval's diagnostics lack COLMAP's label and the focals (their cost is per pair); triage adds them for a
    listed pair from the pair evaluated again, with the same tags as the full diagnostics give."""
    result = evaluate_pair(planar, [("magsac", get_estimator("magsac"))])
    rec = {"error": None, "result": result.to_dict(), "diagnostics": diagnose(planar, result, two_view=False)}
    assert not has_two_view(rec["diagnostics"]) and "focals" not in rec["diagnostics"]["estimators"]["magsac"]
    listed = Ranked(0, 0, "planar", 0.0, False, tag_pair(rec, "magsac"))
    assert "colmap-planar" not in [t for t, _ in listed.tags]
    add_two_view(listed, rec, planar, result, "magsac")
    assert rec["diagnostics"]["two_view"] == "planar" and len(rec["diagnostics"]["estimators"]["magsac"]["focals"]) == 2
    full = {**rec, "diagnostics": diagnose(planar, result)}
    assert [t for t, _ in listed.tags] == [t for t, _ in tag_pair(full, "magsac")] and "colmap-planar" in dict(listed.tags)
