"""Threshold sweeps: NAME@T, the per-pair oracle NAME@oracle, --threshold sweep / lists through the CLI."""

import csv
import json

import numpy as np
import pytest

from cli_util import assert_one_line_error, run_fviz
from fviz.errors import FvizError
from fviz.estimators import get_estimator, run_estimator
from fviz.estimators.features import detect, match
from fviz.estimators.registry import display_names, is_oracle
from fviz.estimators.sweep import SWEEP_GRID_PX, sweep_specs
from fviz.geometry import sampson_distance
from fviz.geometry import symmetric_epipolar_distance as sed


@pytest.fixture(scope="module")
def temporal(odometry):
    pair = odometry.pair(8, "temporal")  # KITTI's pose is ~2 px off here: the thresholds give different F
    return pair, match(detect(pair.image_a), detect(pair.image_b))


def test_sweep_expands_robust_estimators_only():
    specs = sweep_specs(("8point", "magsac", "ahead"), SWEEP_GRID_PX)
    assert specs == ("8point", *(f"magsac@{t:g}" for t in SWEEP_GRID_PX), "magsac@oracle", "ahead")
    names = display_names(specs)
    assert names[1:7] == ["magsac-th0.25", "magsac-th0.5", "magsac-th1", "magsac-th2", "magsac-th4", "magsac-th-oracle"]
    assert [is_oracle(n) for n in names] == [False] * 6 + [True, False]
    assert sweep_specs(("poselib",), (0.5, 2.0))[-1] == "poselib@oracle=0.5,2"


@pytest.mark.parametrize("name", ["magsac", "colmap"])
def test_a_spec_threshold_is_the_estimators_threshold(temporal, name):
    pair, m = temporal
    est = run_estimator(name, get_estimator(f"{name}@0.5"), pair, m.x_a, m.x_b)
    assert np.mean((sampson_distance(est.F, m.x_a, m.x_b) < 0.5) == est.inliers) > 0.99
    wide = run_estimator(name, get_estimator(f"{name}@4"), pair, m.x_a, m.x_b)
    assert wide.inliers.sum() > est.inliers.sum()


def test_the_oracle_keeps_the_grid_f_closest_to_the_ground_truth(temporal):
    pair, m = temporal
    near = sed(pair.F_gt, m.x_a, m.x_b) < 2.0
    grid = {t: run_estimator("x", get_estimator(f"magsac@{t:g}"), pair, m.x_a, m.x_b).F for t in SWEEP_GRID_PX}
    errors = {t: np.median(sed(F, m.x_a[near], m.x_b[near])) for t, F in grid.items()}
    assert len(set(errors.values())) > 1  # the sweep changes the answer on this pair
    oracle = run_estimator("x", get_estimator("magsac@oracle"), pair, m.x_a, m.x_b)
    np.testing.assert_array_equal(oracle.F, grid[min(errors, key=errors.get)])


@pytest.mark.parametrize("spec", ["magsac@0", "magsac@1,2", "magsac@oracle=1,x", "magsac@oraclex"])
def test_bad_threshold_specs_are_refused(spec):
    with pytest.raises(FvizError, match=spec.split("@")[0]):
        get_estimator(spec)


def test_eval_sweep_reports_the_curve_and_the_oracles(kitti_root, tmp_path):
    out = tmp_path / "run"
    proc = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", "6:10",
                    "-e", "usac-prosac", "-e", "8point", "--threshold", "0.5,2", "--out-dir", out, "--workers", "1",
                    "--no-progress", timeout=300)
    assert proc.returncode == 0, proc.stderr
    with open(out / "metrics.csv") as f:
        names = list(dict.fromkeys(r["estimator"] for r in csv.DictReader(f)))
    assert names == ["gt", "usac-prosac-th0.5", "usac-prosac-th2", "usac-prosac-th-oracle", "8point"]
    doc = json.loads((out / "summary.json").read_text())
    assert doc["estimators"]["usac-prosac-th-oracle"]["oracle"] and not doc["estimators"]["usac-prosac-th2"]["oracle"]
    sweep = doc["threshold_sweep"]["usac-prosac"]
    auc = {t: doc["estimators"][n]["pose_auc"]["10"] for t, n in sweep["names"].items()}
    assert sweep["best_over_run_px"] == max(auc, key=lambda t: (auc[t], -float(t)))
    assert sum(sweep["oracle_chose"].values()) == doc["pairs"] > 0  # each pair's oracle F is one of the grid's
    md = (out / "summary.md").read_text()
    assert "## Threshold sweep" in md and "| usac-prosac | per-pair oracle |" in md and "*best over the run*" in md


def test_a_bad_threshold_list_is_one_line(kitti_root, tmp_path):
    r = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--threshold", "1,x",
                 "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, "--threshold '1,x': expected numbers > 0")
    assert not any(tmp_path.iterdir())
