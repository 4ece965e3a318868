"""PoseLib, COLMAP and OpenCV's USAC presets on the real samples, each against an independent result."""

import subprocess
import sys

import numpy as np
import pytest

from fviz.estimators import get_estimator, run_estimator
from fviz.estimators.classical import USAC_FLAGS, RobustConfig
from fviz.estimators.external import METHODS
from fviz.estimators.features import FeatureConfig, detect, match
from fviz.geometry import epipoles, lines_in_a, lines_in_b, homogeneous, recover_pose, sampson_distance
from fviz.geometry import rotation_error_deg, translation_error_deg
from fviz.geometry import symmetric_epipolar_distance as sed

NEW = [*USAC_FLAGS, *METHODS]
SAMPSON = ["magsac", *(n for n in NEW if n != "poselib-E")]  # --threshold: their own F's Sampson distance


def _matched(pair):
    cfg = FeatureConfig()
    return pair, match(detect(pair.image_a, cfg), detect(pair.image_b, cfg), cfg)


@pytest.fixture(scope="module")
def temporal(odometry):
    return _matched(odometry.pair(3, "temporal"))


@pytest.fixture(scope="module")
def stereo(odometry):
    return _matched(odometry.pair(0, "stereo"))


@pytest.fixture(scope="module")
def estimates(temporal, stereo):
    """(temporal, stereo) Estimate of every new estimator and of magsac, at the default 1 px."""
    return {name: tuple(run_estimator(name, get_estimator(name), p, m.x_a, m.x_b) for p, m in (temporal, stereo))
            for name in [*NEW, "magsac"]}


@pytest.mark.parametrize("name", NEW)
def test_new_estimators_fit_the_matches_and_agree_with_the_ground_truth(estimates, temporal, stereo, name):
    for (pair, m), est, gt_px in ((temporal, estimates[name][0], 3.0), (stereo, estimates[name][1], None)):
        assert est.ok, est.error
        assert est.inliers.shape == (len(m),) and est.inliers.mean() > 0.8
        xa, xb = m.x_a[est.inliers], m.x_b[est.inliers]
        assert np.median(sampson_distance(est.F, xa, xb)) < 0.5
        gt = sed(pair.F_gt, xa, xb)
        if gt_px:  # temporal: KITTI's poses are good to a few px
            assert np.median(gt) < gt_px
        else:  # stereo: the calibration is good to < 0.5 px, the inliers sit within ~1 px of F_gt
            assert np.median(gt) < 0.5 and np.percentile(gt, 90) < 1.0


@pytest.mark.parametrize("name", ["poselib", "colmap", "usac-default"])
def test_poselib_colmap_and_usac_agree_with_magsac_within_their_residuals(estimates, temporal, name):
    """Each F explains MAGSAC++'s inliers about as well as MAGSAC++'s own F does, and vice versa."""
    _, m = temporal
    mine, ref = estimates[name][0], estimates["magsac"][0]
    for F, inl, other in ((mine.F, ref.inliers, ref.F), (ref.F, mine.inliers, mine.F)):
        own = np.median(sampson_distance(other, m.x_a[inl], m.x_b[inl]))
        assert np.median(sampson_distance(F, m.x_a[inl], m.x_b[inl])) < 2 * own + 0.1
    ra, rb = (np.linalg.solve(temporal[0].K_a, epipoles(F)[0]) for F in (mine.F, ref.F))
    cos = abs(ra @ rb) / np.linalg.norm(ra) / np.linalg.norm(rb)
    assert np.degrees(np.arccos(min(1.0, cos))) < 2.0  # epipole rays (motion direction): 0.07-0.75 deg apart


@pytest.mark.parametrize("name", SAMPSON)
@pytest.mark.parametrize("threshold", [0.5, 2.0])
def test_threshold_is_the_sampson_distance_in_px(temporal, name, threshold):
    pair, m = temporal
    est = run_estimator(name, get_estimator(name, RobustConfig(threshold=threshold)), pair, m.x_a, m.x_b)
    agree = np.mean((sampson_distance(est.F, m.x_a, m.x_b) < threshold) == est.inliers)
    assert agree > 0.99, agree


def test_threshold_of_poselib_e_is_in_px_and_ransac_is_the_larger_line_distance(temporal):
    pair, m = temporal
    small, large = (run_estimator("poselib-E", get_estimator("poselib-E", RobustConfig(threshold=t)), pair, m.x_a, m.x_b)
                    for t in (0.5, 2.0))
    assert small.inliers.sum() < large.inliers.sum()
    for est, t in ((small, 0.5), (large, 2.0)):  # PoseLib scales px by the focal: about a Sampson px
        assert np.mean((sampson_distance(est.F, m.x_a, m.x_b) < t) == est.inliers) > 0.95
    est = run_estimator("ransac", get_estimator("ransac"), pair, m.x_a, m.x_b)
    d = np.maximum(np.abs(np.einsum("ni,ni->n", lines_in_a(est.F, m.x_b), homogeneous(m.x_a))),
                   np.abs(np.einsum("ni,ni->n", lines_in_b(est.F, m.x_a), homogeneous(m.x_b))))
    assert np.mean((d < 1.0) == est.inliers) > 0.99


def test_poselib_e_recovers_the_true_motion(estimates, temporal):
    pair, m = temporal
    est = estimates["poselib-E"][0]
    R, t = recover_pose(est.F, pair.K_a, pair.K_b, m.x_a[est.inliers], m.x_b[est.inliers])
    assert rotation_error_deg(R, pair.R) < 0.5
    assert translation_error_deg(t, pair.t / np.linalg.norm(pair.t)) < 5.0


@pytest.mark.parametrize("name", [*METHODS, "usac-default", "usac-prosac"])
def test_new_estimators_are_deterministic(temporal, name):
    """The same seed twice: the same F. Another seed: another F for PoseLib and COLMAP (they take --seed); the same
    for the usac-* presets (OpenCV's flag API fixes their random state)."""
    pair, m = temporal
    runs = [run_estimator(name, get_estimator(name, RobustConfig(seed=s)), pair, m.x_a, m.x_b).F for s in (4, 4, 5)]
    np.testing.assert_array_equal(runs[0], runs[1])
    assert np.array_equal(runs[0], runs[2]) != (name in METHODS)


@pytest.mark.parametrize("name", NEW)
def test_too_few_matches_is_an_estimator_error(temporal, name):
    pair, m = temporal
    est = run_estimator(name, get_estimator(name), pair, m.x_a[:4], m.x_b[:4])
    assert not est.ok and "at least" in est.error and "got 4" in est.error


def test_poselib_and_pycolmap_load_only_when_used():
    code = "import sys, fviz.cli, fviz.estimators.registry as r; r.get_estimator('poselib'); r.get_estimator('colmap'); " \
           "print(sorted(m for m in ('poselib', 'pycolmap') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
