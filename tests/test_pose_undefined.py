"""Pose of an F with too few evaluation matches: the decomposition is chosen
with the ground truth's own points where the source knows them (synthetic scenes), never the estimate's matches;
otherwise the pose is *undefined*, kept apart from failures in the figures."""

from __future__ import annotations

import json
import math

from cli_util import run_fviz


def _json(*args):
    proc = run_fviz("inspect", "pair", *args, "--json", timeout=300)
    assert proc.returncode in (0, 1), proc.stderr
    return {e["name"]: e for e in json.loads(proc.stdout)["estimators"]}, json.loads(proc.stdout)


def test_ground_truth_points_choose_the_decomposition_when_matches_are_too_few(tmp_path):
    ests, doc = _json("--synthetic", "--seed", "0", "--pair", "temporal", "--eval-threshold", "1e-6", "--out", tmp_path / "s.rrd")
    assert doc["n_eval"] < 5
    for name in ("ransac", "magsac"):
        m = ests[name]["metrics"]
        assert "pose_undefined" not in m and m["rot_err_deg"] is not None and math.isfinite(m["rot_err_deg"]), name


def test_without_ground_truth_points_the_pose_is_undefined_not_failed(kitti_root, tmp_path):
    ests, doc = _json("--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frame", "3",
                      "--eval-threshold", "1e-4", "--out", tmp_path / "k.rrd")
    assert doc["n_eval"] < 5
    assert all(ests[n]["metrics"]["pose_undefined"] == 1.0 and ests[n]["error"] is None for n in ("ransac", "magsac"))
    out = tmp_path / "run"
    proc = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", "3:6",
                    "--eval-threshold", "1e-4", "-e", "magsac", "--workers", "1", "--no-progress", "--out-dir", out, timeout=600)
    assert proc.returncode == 0, proc.stderr
    fig = json.loads((out / "summary.json").read_text())["estimators"]["magsac"]
    # counted apart, and in the field's AUC as failures of the estimate (the matcher gave too few)
    assert fig["errors"] == 0 and fig["pose_undefined"] == 2 and fig["with_pose_pairs"] == 0
    assert fig["pose_pairs"] == fig["pairs"] and fig["pose_auc"] == {"5": 0.0, "10": 0.0, "20": 0.0}
    assert "Undefined (too few matches): magsac 2 pairs" in (out / "summary.md").read_text()
