"""Features, classical estimators and the registry on the real samples."""

import sys

import numpy as np
import pytest

from fviz.errors import FvizError
from fviz.estimators import get_estimator, run_estimator
from fviz.estimators.classical import MIN_MATCHES, RobustConfig
from fviz.estimators.features import FeatureCache, FeatureConfig, Features, detect, match
from fviz.estimators.registry import display_name
from fviz.geometry import f_distance, sampson_distance
from fviz.geometry import symmetric_epipolar_distance as sed


@pytest.fixture(scope="module")
def temporal(odometry):
    pair = odometry.pair(3, "temporal")
    cfg = FeatureConfig()
    return pair, match(detect(pair.image_a, cfg), detect(pair.image_b, cfg), cfg)


@pytest.mark.parametrize("kind", ["sift", "orb", "akaze"])
def test_every_feature_type_matches_consistently_with_ground_truth(temporal, kind):
    pair = temporal[0]
    cfg = FeatureConfig(kind=kind)
    m = match(detect(pair.image_a, cfg), detect(pair.image_b, cfg), cfg)
    assert len(m) > 100
    assert np.median(sed(pair.F_gt, m.x_a, m.x_b)) < 3.0


def test_mutual_check_and_ratio_only_remove_matches(temporal):
    pair = temporal[0]
    fa, fb = detect(pair.image_a), detect(pair.image_b)
    loose = match(fa, fb, FeatureConfig(ratio=0.9, mutual=False))
    strict = match(fa, fb, FeatureConfig(ratio=0.7, mutual=True))
    assert len(strict) < len(loose)
    assert set(map(tuple, strict.idx)) <= set(map(tuple, loose.idx))
    assert np.all(np.diff(loose.distance) >= 0)  # best first


def test_feature_cache_detects_each_image_once(odometry):
    cache = FeatureCache(FeatureConfig())
    for f in range(3):
        p = odometry.pair(f, "temporal")
        cache.get(p.id.key_a, p.image_a), cache.get(p.id.key_b, p.image_b)
    assert (cache.misses, cache.hits) == (4, 2)


@pytest.mark.parametrize("name", sorted(MIN_MATCHES))
def test_classical_estimators_find_a_valid_f(temporal, name):
    pair, m = temporal
    est = run_estimator(name, get_estimator(name), pair, m.x_a, m.x_b)
    assert est.ok, est.error
    s = np.linalg.svd(est.F, compute_uv=False)
    assert s[2] < 1e-9 * s[0] < s[1], s  # rank 2, exactly (OpenCV's solvers zero the smallest singular value)
    assert est.inliers.shape == (len(m),) and est.inliers.sum() >= 7
    if name in ("lmeds", "ransac", "magsac"):
        assert np.median(sampson_distance(est.F, m.x_a[est.inliers], m.x_b[est.inliers])) < 0.5
        assert np.median(sed(pair.F_gt, m.x_a[est.inliers], m.x_b[est.inliers])) < 3.0


@pytest.mark.parametrize("name, seeded", [("magsac", True), ("ransac", False), ("lmeds", False)])
def test_robust_estimators_are_deterministic_and_magsac_follows_the_seed(temporal, name, seeded):
    """The same seed twice: the same F. Another seed: another F for MAGSAC++ (its USAC random state); the same
    for ransac and lmeds, whose OpenCV RANSAC fixes its own random generator (``cv2.setRNGSeed`` has no effect)."""
    pair, m = temporal
    runs = [run_estimator(name, get_estimator(name, RobustConfig(seed=s)), pair, m.x_a, m.x_b).F for s in (3, 3, 4)]
    np.testing.assert_array_equal(runs[0], runs[1])
    assert np.array_equal(runs[0], runs[2]) != seeded


def test_fewer_than_eight_matches_is_an_estimator_error(temporal):
    pair, m = temporal
    est = run_estimator("magsac", get_estimator("magsac"), pair, m.x_a[:6], m.x_b[:6])
    assert not est.ok and "at least 8 matches, got 6" in est.error


def test_user_function_plugs_in_and_failures_are_caught(tmp_path, temporal, monkeypatch):
    pair, m = temporal
    (tmp_path / "my_estimators.py").write_text(
        "import cv2, numpy as np\n"
        "def eight(pair, x_a, x_b):\n"
        "    return cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)[0]\n"
        "def nan_f(pair, x_a, x_b):\n"
        "    return np.full((3, 3), np.nan)\n"
        "def broken(pair, x_a, x_b):\n"
        "    raise RuntimeError('solver diverged')\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("my_estimators", None)
    ok = run_estimator("u", get_estimator("my_estimators:eight"), pair, m.x_a, m.x_b)
    ref = run_estimator("8point", get_estimator("8point"), pair, m.x_a, m.x_b)
    assert ok.ok and ok.inliers is None and f_distance(ok.F, ref.F) < 1e-9
    assert "no valid 3x3 F" in run_estimator("n", get_estimator("my_estimators:nan_f"), pair, m.x_a, m.x_b).error
    assert "RuntimeError: solver diverged" in run_estimator("b", get_estimator("my_estimators:broken"), pair, m.x_a, m.x_b).error
    assert display_name("my_estimators:eight") == "eight"
    assert display_name("deep:runs/x/best.pt") == "deep-best"


def test_unknown_estimators_are_usage_errors():
    with pytest.raises(FvizError, match="unknown.*magsac"):
        get_estimator("magsack")
    with pytest.raises(FvizError, match="cannot import module 'nope'"):
        get_estimator("nope:f")
    with pytest.raises(FvizError, match="has no function 'nothing'"):
        get_estimator("fviz.geometry:nothing")
    with pytest.raises(FvizError, match="--threshold"):
        RobustConfig(threshold=0)
    with pytest.raises(FvizError, match="--features"):
        FeatureConfig(kind="surf")


def _opencv_matches(da, db, norm, ratio=0.8):
    """Ratio test + mutual check written with OpenCV's brute-force matcher, as its users do."""
    import cv2

    bf = cv2.BFMatcher(norm)
    back = {m.queryIdx: m.trainIdx for m in bf.match(db, da)}
    return {(m.queryIdx, m.trainIdx) for m, n in bf.knnMatch(da, db, k=2)
            if m.distance < ratio * n.distance and back.get(m.trainIdx) == m.queryIdx}


@pytest.mark.parametrize("kind", ["sift", "orb"])
@pytest.mark.parametrize("frame, pair_kind, step", [(3, "temporal", 1), (0, "temporal", 4), (20, "temporal", 1), (0, "stereo", 1)])
def test_matching_equals_opencv_brute_force(odometry, kind, frame, pair_kind, step):
    import cv2

    pair = odometry.pair(frame, pair_kind, step)
    cfg = FeatureConfig(kind=kind)
    fa, fb = detect(pair.image_a, cfg), detect(pair.image_b, cfg)
    ref = _opencv_matches(fa.descriptors, fb.descriptors, cv2.NORM_L2 if kind == "sift" else cv2.NORM_HAMMING)
    got = match(fa, fb, cfg)
    assert len(got) > 50
    assert set(map(tuple, got.idx)) == ref
    if kind == "orb":
        return
    # L2 distances equal a float64 computation (SIFT descriptors are integers: exact in float32)
    d_ref = np.linalg.norm(fa.descriptors[got.idx[:, 0]].astype(np.float64) - fb.descriptors[got.idx[:, 1]], axis=1)
    np.testing.assert_allclose(got.distance, d_ref, rtol=1e-6)


@pytest.mark.parametrize("block", [1, 7, 64])
def test_matching_in_blocks_of_rows_equals_opencv(monkeypatch, block):
    """The distance matrix is reduced a block of rows at a time: ties and nearest neighbours that fall in
    other blocks than their rivals' still resolve as OpenCV's brute-force matcher does."""
    import cv2

    import fviz.estimators.features as features

    monkeypatch.setattr(features, "MATCH_BLOCK", block)
    rng = np.random.default_rng(1)
    db = rng.integers(0, 60, (200, 128)).astype(np.float32)
    da = (db[:120] + rng.integers(0, 2, (120, 128))).astype(np.float32)
    da[100:120] = da[:20]  # a tie between rows far apart (in different blocks)
    db[180:] = db[160:180]
    fa = Features(rng.uniform(0, 100, (len(da), 2)), da)
    fb = Features(rng.uniform(0, 100, (len(db), 2)), db)
    for ratio in (0.8, 1.0):
        got = set(map(tuple, match(fa, fb, FeatureConfig(ratio=ratio)).idx))
        assert got == _opencv_matches(da, db, cv2.NORM_L2, ratio) and len(got) > 30


def test_matching_ties_go_to_the_lowest_index_like_opencv():
    """Duplicated descriptors tie exactly: OpenCV keeps the lowest index, so must the GEMM matcher."""
    import cv2

    rng = np.random.default_rng(0)
    db = rng.integers(0, 60, (300, 128)).astype(np.float32)
    da = np.concatenate([db[:100] + rng.integers(0, 2, (100, 128)), db[:50] + rng.integers(0, 2, (50, 128))]).astype(np.float32)
    da[120:150] = da[20:50]  # rows 120..149 repeat rows 20..49: their columns' minima are tied
    db[250:] = db[200:250]  # tied second-nearest neighbours for the ratio test
    fa = Features(rng.uniform(0, 100, (len(da), 2)), da)
    fb = Features(rng.uniform(0, 100, (len(db), 2)), db)
    for ratio in (0.8, 1.0):
        cfg = FeatureConfig(ratio=ratio)
        ref = _opencv_matches(da, db, cv2.NORM_L2, ratio)
        got = set(map(tuple, match(fa, fb, cfg).idx))
        assert got == ref and len(ref) > 50
        assert not any(20 <= i < 50 and (i + 100, j) in got for i, j in got)  # ties resolved to the lower row
