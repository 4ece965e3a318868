"""Figures comparable with the field's: the standard pose AUC counts every pair with a
ground-truth pose, as SuperGlue / LightGlue / glue-factory do (no F, no pose, or a pose undefined for want of
evaluation matches is an infinite error); the AUC over the pairs with a pose is a second, named figure; the
ground truth's own row never shows errors, its pairs with too few matches are counted apart as undefined."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from cli_util import read_csv, run_fviz

from fviz.evaluate import GT_NAME
from fviz.run.reports import UNDEFINED, UNDEFINED_COLUMN, WITH_POSE, standard_figures

THRESHOLDS = (5.0, 10.0, 20.0)


def superglue_pose_auc(errors, thresholds=THRESHOLDS):
    """SuperGlue's ``pose_auc`` (magicleap/SuperGluePretrainedNetwork, models/utils.py), written out again here: a
    failed pose is passed in as an infinite error, sorted last, never reaching a threshold."""
    errors = np.sort(np.asarray(errors, float))
    recall = (np.arange(len(errors)) + 1) / len(errors)
    errors, recall = np.r_[0.0, errors], np.r_[0.0, recall]
    aucs = []
    for t in thresholds:
        last = np.searchsorted(errors, t)
        r, e = np.r_[recall[:last], recall[last - 1]], np.r_[errors[:last], t]
        aucs.append(float(np.sum((e[1:] - e[:-1]) * (r[1:] + r[:-1])) / 2.0 / t))  # trapezoids
    return aucs


def test_standard_figures_count_undefined_pairs_as_failures():
    """Six pairs: four with a pose, one without F, one whose pose is undefined (too few evaluation matches)."""
    nan = math.nan
    # per pair: pose_err_deg, nsgd, sed_median, sampson_median
    est = [[1.0, 0.01, 0.3, 0.2], [3.0, 0.02, 0.4, 0.3], [12.0, 0.2, 2.5, 1.8], [7.0, 0.03, 0.5, 0.4],
           [nan, nan, nan, nan], [nan, 0.04, nan, nan]]
    gt = [[0.0, 0.0, 0.3, 0.2]] * 4 + [[0.0, 0.0, nan, nan]] * 2
    kinds = {"e": ["pose"] * 5 + [UNDEFINED], GT_NAME: ["pose"] * 4 + [UNDEFINED] * 2}
    f = standard_figures({"e": np.ravel(est), GT_NAME: np.ravel(gt)}, ["e", GT_NAME], pair_gt=kinds, failures={"e": 1})
    every = superglue_pose_auc([1.0, 3.0, 12.0, 7.0, np.inf, np.inf])
    assert list(f["e"]["pose_auc"].values()) == pytest.approx(every)
    assert list(f["e"]["pose_auc_with_pose"].values()) == pytest.approx(superglue_pose_auc([1.0, 3.0, 12.0, 7.0, np.inf]))
    assert (f["e"]["pose_pairs"], f["e"]["with_pose_pairs"], f["e"]["pose_undefined"], f["e"]["errors"]) == (6, 5, 1, 1)
    # the reference: never an error, a fail or a miss; its two pairs without residuals are undefined
    g = f[GT_NAME]
    assert (g["errors"], g["fails"], g["pose_undefined"], g["nsgd_recall"]) == (0, 0, 2, 1.0)
    assert list(g["pose_auc"].values()) == [1.0, 1.0, 1.0]


def _eval(kitti_root, out, *flags, frames="0:8"):
    proc = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", frames,
                    "-e", "magsac", "--workers", "1", "--no-progress", *flags, "--out-dir", out, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return proc, json.loads((out / "summary.json").read_text())["estimators"]


@pytest.mark.kitti
def test_pose_auc_is_superglues_over_every_pair(kitti_root, tmp_path):
    """A tight evaluation threshold leaves some KITTI pairs with fewer than 5 evaluation matches: their pose is
    undefined, and the standard AUC is SuperGlue's pose_auc with those pairs at an infinite error."""
    out = tmp_path / "run"
    proc, figs = _eval(kitti_root, out, "--eval-threshold", "0.05", "--max-keypoints", "400")
    rows = [r for r in read_csv(out / "metrics.csv") if r["estimator"] == "magsac"]
    undefined = [r.get("pose_undefined") in ("1", "1.0") for r in rows]
    assert 0 < sum(undefined) < len(rows)  # the case the figure is about: some pairs with a pose, some without
    errors = [np.inf if u or r["error"] or r["pose_err_deg"] in ("", "nan") else float(r["pose_err_deg"])
              for r, u in zip(rows, undefined)]
    f = figs["magsac"]
    assert list(f["pose_auc"].values()) == pytest.approx(superglue_pose_auc(errors), abs=1e-12)
    posed = [e for e, u in zip(errors, undefined) if not u]
    assert list(f["pose_auc_with_pose"].values()) == pytest.approx(superglue_pose_auc(posed), abs=1e-12)
    assert f["pose_auc"]["20"] < f["pose_auc_with_pose"]["20"]
    assert (f["pose_pairs"], f["with_pose_pairs"], f["pose_undefined"]) == (len(rows), len(posed), sum(undefined))
    # every table says the undefined pairs apart: summary.md, eval's printed table, fviz table
    md = (out / "summary.md").read_text()
    assert f"({WITH_POSE})" in md and UNDEFINED_COLUMN in md and f"| {sum(undefined)}/{len(rows)} |" in md
    assert "pairs with a pose" in proc.stdout.replace("\n", " ") or "(pairs with a" in proc.stdout
    from fviz.table import run_figures

    assert run_figures(out)["magsac"]["pose_auc"] == pytest.approx(f["pose_auc"])
    assert run_figures(out)["magsac"]["pose_auc_with_pose"] == pytest.approx(f["pose_auc_with_pose"])


@pytest.mark.kitti
def test_the_ground_truth_never_shows_errors_on_pairs_with_too_few_matches(kitti_root, tmp_path):
    """12 keypoints per image: every pair has fewer than 8 matches and fails as a whole for the estimators; the
    ground truth's row shows no error, a pose AUC and NSGD recall of 1, and those pairs as undefined."""
    out = tmp_path / "run"
    _, figs = _eval(kitti_root, out, "--max-keypoints", "12", frames="0:4")
    rows = read_csv(out / "metrics.csv")
    assert all(r["pair_error"].startswith("only ") for r in rows)
    g, m = figs[GT_NAME], figs["magsac"]
    assert (g["errors"], g["fails"], g["pose_undefined"], g["pairs"]) == (0, 0, 3, 3)
    assert g["pose_auc"] == {"5": 1.0, "10": 1.0, "20": 1.0} and g["nsgd_recall"] == 1.0
    assert m["errors"] == 3 and m["pose_auc"] == {"5": 0.0, "10": 0.0, "20": 0.0}
    md = (out / "summary.md").read_text()
    gt_row = next(line for line in md.splitlines() if line.startswith("| ground truth | 1 |"))
    assert gt_row.endswith("| 0/3 | 0/3 |") and "| 3/3 |" in gt_row, gt_row  # errors, fails; undefined
    from fviz.table import run_figures

    t = run_figures(out)[GT_NAME]
    assert (t["errors"], t["pose_undefined"], t["nsgd_recall"]) == (0, 3, 1.0)
    from fviz.compare import Side, read_side

    assert all(not e for _, e in read_side(Side(str(out), GT_NAME), "nsgd").values())
