"""Match precision before any estimator: glue-factory's epi_prec and px shares, against OpenCV's epipolar
lines, in inspect's JSON and summary and in eval's summary.md / summary.json."""

import csv
import json

import cv2
import numpy as np
import pytest

from cli_util import run_fviz
from fviz.estimators.features import detect, match
from fviz.evaluate import evaluate_pair
from fviz.geometry import PRECISION_KEYS, match_precision, normalized_epipolar_distance, skew


@pytest.fixture(scope="module")
def temporal(odometry):
    pair = odometry.pair(3, "temporal")
    return pair, match(detect(pair.image_a), detect(pair.image_b))


def _opencv_distance(F, x_a, x_b):
    """Mean of the two point-to-line distances, lines from cv2.computeCorrespondEpilines (unit normals)."""
    l_b = cv2.computeCorrespondEpilines(x_a.reshape(-1, 1, 2), 1, F).reshape(-1, 3)
    l_a = cv2.computeCorrespondEpilines(x_b.reshape(-1, 1, 2), 2, F).reshape(-1, 3)
    d = lambda l, x: np.abs(l[:, 0] * x[:, 0] + l[:, 1] * x[:, 1] + l[:, 2])  # noqa: E731
    return (d(l_b, x_b) + d(l_a, x_a)) / 2


def test_normalized_distance_is_the_epipolar_distance_of_e_on_opencv_normalized_points(temporal):
    pair, m = temporal
    n_a = cv2.undistortPoints(m.x_a.reshape(-1, 1, 2), pair.K_a, None).reshape(-1, 2)
    n_b = cv2.undistortPoints(m.x_b.reshape(-1, 1, 2), pair.K_b, None).reshape(-1, 2)
    E = skew(pair.t / np.linalg.norm(pair.t)) @ pair.R
    mine = normalized_epipolar_distance(pair.K_a, pair.K_b, pair.R, pair.t, m.x_a, m.x_b)
    np.testing.assert_allclose(mine, _opencv_distance(E, n_a, n_b), rtol=1e-6, atol=1e-12)
    # KITTI's pixels are square (fx = fy = f): the normalized distance is the pixel one over f
    np.testing.assert_allclose(mine * pair.K_a[0, 0], _opencv_distance(pair.F_gt, m.x_a, m.x_b), rtol=1e-4)


def test_match_precision_counts_the_shares_under_each_threshold(temporal):
    pair, m = temporal
    prec = match_precision(pair.K_a, pair.K_b, pair.R, pair.t, pair.F_gt, m.x_a, m.x_b)
    assert tuple(prec) == PRECISION_KEYS
    px = _opencv_distance(pair.F_gt, m.x_a, m.x_b)
    norm = px / pair.K_a[0, 0]
    for t in (1, 2, 4):
        assert prec[f"px_prec@{t}"] == pytest.approx(np.mean(px < t), abs=2 / len(px))
    for name, t in (("1e-4", 1e-4), ("5e-4", 5e-4), ("1e-3", 1e-3)):
        assert prec[f"epi_prec@{name}"] == pytest.approx(np.mean(norm < t), abs=2 / len(px))
    assert 0 < prec["epi_prec@1e-4"] < prec["epi_prec@1e-3"] < prec["px_prec@1"] < prec["px_prec@4"] <= 1
    empty = match_precision(pair.K_a, pair.K_b, pair.R, pair.t, pair.F_gt, m.x_a[:0], m.x_b[:0])
    assert all(np.isnan(v) for v in empty.values())


def test_stereo_matches_are_precise_and_the_result_carries_it(odometry):
    result = evaluate_pair(odometry.pair(0, "stereo"), [])
    prec = result.to_dict()["match_precision"]
    assert prec["px_prec@2"] > 0.9 and prec["px_prec@4"] >= prec["px_prec@2"]
    assert all(row["px_prec@2"] == prec["px_prec@2"] for row in result.rows())


def test_inspect_and_eval_report_match_precision_and_time(kitti_root, tmp_path):
    proc = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "stereo", "-e", "magsac",
                    "-e", "poselib", "--json", "--out", tmp_path / "p.rrd")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert set(doc["match_precision"]) == set(PRECISION_KEYS) and doc["match_precision"]["px_prec@2"] > 0.9
    out = tmp_path / "run"
    proc = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", "0:4",
                    "-e", "usac-prosac", "-e", "colmap", "--out-dir", out, "--workers", "1", "--no-progress", timeout=300)
    assert proc.returncode == 0, proc.stderr
    with open(out / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    summary = json.loads((out / "summary.json").read_text())
    for est in ("usac-prosac", "colmap"):
        secs = [float(r["seconds"]) for r in rows if r["estimator"] == est]
        assert summary["seconds"][est]["median"] == pytest.approx(float(np.median(secs)))
        assert summary["seconds"][est]["p90"] == pytest.approx(float(np.percentile(secs, 90)))
    gt_rows = [r for r in rows if r["estimator"] == "gt"]
    assert summary["match_precision"]["px_prec@1"] == pytest.approx(np.mean([float(r["px_prec@1"]) for r in gt_rows]))
    md = (out / "summary.md").read_text()
    assert "## Time per pair" in md and "| colmap | " in md and "## Match precision (before any estimator)" in md
