"""heldout.json's verdict fields: pose AUC@5/10/20 and the paired tests of the model against the straight-ahead
constant and the training pairs' mean F, checked against independent computations (the closed form of the AUC,
the straight-ahead pose error from the ground-truth motion, scipy's Wilcoxon test)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fviz.data.kitti import open_dataset
from fviz.train.heldout import NO_BETTER, PAIRED_METRICS, heldout_report
from fviz.train.recipe import Recipe

WEIGHTS = Path(__file__).resolve().parents[1] / "assets" / "fviz-deep.pt"


def _auc(errors, th):
    """SuperGlue's AUC by brute force: the recall curve through (0, 0) and (e_i, i / N), linear between its points
    and flat past the last error below th, integrated on a fine grid up to th, over th (a failure: never recalled)."""
    e = np.sort(np.asarray(errors, np.float64))
    e = e[np.isfinite(e)]
    xs = np.r_[0.0, e[e < th]]
    ys = np.arange(len(xs)) / len(errors)
    grid = np.linspace(0.0, th, 400001)
    return float(np.trapezoid(np.interp(grid, xs, ys), grid) / th)


def _angle(u, v):
    c = abs(float(np.dot(u, v))) / (np.linalg.norm(u) * np.linalg.norm(v))
    return math.degrees(math.acos(min(1.0, c)))


@pytest.fixture(scope="module")
def report(kitti_root, tmp_path_factory):
    if not WEIGHTS.is_file():
        pytest.skip("bundled weights absent")
    recipe = Recipe.from_dict({
        "model": {"variant": "siamese-rec-pos-fbn"},
        "data": {"source": "kitti-odometry", "root": str(kitti_root), "sequences": ["02"], "val_sequences": ["10"],
                 "cameras": [2], "frames": [0, 5]},
        "train": {"out_dir": str(tmp_path_factory.mktemp("run"))},
    })
    return heldout_report(recipe, str(WEIGHTS))


def test_report_names_what_the_drives_chose(report):
    assert report["sequences"] == ["10"] and report["trained_on"] == ["02"]
    assert report["chose"].startswith("nothing")  # no train.keep_best: the last step is the model
    assert set(report["paired"]) == {"constant", "mean_f"}
    for other in ("constant", "mean_f"):
        assert set(report["paired"][other]) == set(PAIRED_METRICS)
        assert report["beats"][other] == (report["paired"][other]["pose_err_deg"]["verdict"] == "model better")
    # one line beside both constants: no better than the constant unless the paired tests find it better than both
    assert report["verdict"].startswith(NO_BETTER) == (not all(report["beats"].values()))
    assert "for straight-ahead motion" in report["verdict"] and "for the training pairs' mean F" in report["verdict"]


def test_pose_auc_is_the_closed_form_of_the_per_pair_errors(report):
    for name in ("model", "constant", "mean_f"):
        errors = [v["pose_err_deg"] for v in report["per_pair"][name].values()]
        assert len(errors) == 4 == report[name]["pairs"]
        for th in (5, 10, 20):
            assert report[name]["pose_auc"][str(th)] == pytest.approx(_auc(errors, th), abs=1e-6)


def test_straight_ahead_pose_error_is_the_ground_truth_motion(report, kitti_root):
    """R = I, t = z: its pose error is max(the true rotation angle, the angle of the true t to the optical axis)."""
    ds = open_dataset(kitti_root, sequence="10")
    for f in range(4):
        pid = ds.pair_id(f, kind="temporal", step=1, cams=(2, 2))
        _, _, R, t, _ = ds.ground_truth(pid)
        rot = math.degrees(math.acos(min(1.0, (np.trace(R) - 1) / 2)))
        expected = max(rot, _angle(t, np.array([0.0, 0.0, 1.0])))
        assert report["per_pair"]["constant"][pid.name]["pose_err_deg"] == pytest.approx(expected, abs=1e-3)


def test_paired_tests_match_scipy(report):
    from scipy.stats import wilcoxon

    for other in ("constant", "mean_f"):
        for metric in PAIRED_METRICS:
            test = report["paired"][other][metric]
            a, b = report["per_pair"]["model"], report["per_pair"][other]
            d = np.array([a[n][metric] - b[n][metric] for n in a if n in b])
            d = d[np.isfinite(d)]
            assert test["pairs"] == len(a)
            assert test["median_a_minus_b"] == pytest.approx(float(np.median(d)))
            wins = sum(1 for n in a if a[n][metric] < b[n][metric] and
                       abs(a[n][metric] - b[n][metric]) > 0.05 * max(abs(a[n][metric]), abs(b[n][metric])))
            assert test["wins"] == wins
            nz = d[d != 0]
            if len(nz):
                assert test["wilcoxon_p"] == pytest.approx(float(wilcoxon(nz, method="exact").pvalue), rel=1e-6)
                if test["wilcoxon_p"] >= 0.05:
                    assert test["verdict"] == "no difference shown"


def test_the_explicit_names_are_the_bundled_models_as_deep_runs_them(odometry, monkeypatch):
    """deep:motion on a temporal pair and deep:stereo on a stereo pair give deep's F (views and gain included)."""
    from fviz.estimators.deep import STEREO, WEIGHTS_ENV, deep_estimator
    from fviz.estimators.registry import get_estimator

    if not (WEIGHTS.is_file() and STEREO.is_file()):
        pytest.skip("bundled weights absent")
    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    temporal = odometry.load(odometry.pair_id(0, kind="temporal", step=1, cams=(0, 0)))
    stereo = odometry.load(odometry.pair_id(0, kind="stereo"))
    deep = deep_estimator()
    np.testing.assert_allclose(get_estimator("deep:motion")(temporal, None, None), deep(temporal, None, None), atol=1e-12)
    np.testing.assert_allclose(get_estimator("deep:stereo")(stereo, None, None), deep(stereo, None, None), atol=1e-12)
    one_pass = deep_estimator(str(WEIGHTS))(temporal, None, None)  # deep:PATH: one pass, no views
    assert not np.allclose(one_pass / np.linalg.norm(one_pass), deep(temporal, None, None) / np.linalg.norm(deep(temporal, None, None)))


def test_the_manifest_verdicts_carry_pose_auc_and_the_paired_tests_against_both_constants():
    import json

    manifest = json.loads((WEIGHTS.parent / "MANIFEST.json").read_text())
    for verdict in (manifest["verdict"], manifest["stereo_model"]["verdict"]):
        clean_wins = []
        for drive, entry in verdict["heldout"].items():
            assert entry["data"] and entry["chose"] and entry["mean_f"], drive  # every claim names its drive and what it chose
            auc = {name: entry["figures"][name]["pose_auc_5_10_20"] for name in ("deep", "ahead", "mean_f", "magsac")}
            assert all(len(a) == 3 and all(0.0 <= x <= 1.0 for x in a) for a in auc.values())
            beats = all(auc["deep"][i] > auc[c][i] for c in ("ahead", "mean_f") for i in range(3))
            assert entry["deep_beats_both_constants_on_pose_auc"] == beats, drive
            for side in ("vs_ahead", "vs_mean_f"):
                assert set(entry["paired_compare"][side]) == {"pose_err_deg", "sed_median", "rot_err_deg"}
            if entry["chose"].startswith("nothing"):
                clean_wins.append(beats)
        assert clean_wins, "no held-out drive that chose nothing"
        assert verdict["result"].startswith("not met") == (not all(clean_wins))


def test_the_mean_f_constant_is_per_pair_kind(kitti_root, tmp_path):
    """A recipe with temporal and stereo pairs gets one mean F per kind: the stereo one is the rectified rig's F."""
    from fviz.train.heldout import training_mean_f

    recipe = Recipe.from_dict({
        "model": {"variant": "siamese-rec-pos-fbn"},
        "data": {"source": "kitti-odometry", "root": str(kitti_root), "sequences": ["01"], "val_sequences": ["10"],
                 "kinds": ["temporal", "stereo"], "cameras": [0, 1], "frames": [0, 4]},
        "train": {"out_dir": str(tmp_path / "run")},
    })
    means = training_mean_f(recipe)
    assert set(means) == {"temporal", "stereo"}
    F = means["stereo"] / np.linalg.norm(means["stereo"])
    rectified = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]) / math.sqrt(2)
    assert min(np.abs(F - rectified).max(), np.abs(F + rectified).max()) < 1e-9
    assert np.abs(means["temporal"] / np.linalg.norm(means["temporal"]) - F).max() > 0.1
