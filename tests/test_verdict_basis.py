"""The basis of a pair's verdict: evidence only from fits with spare matches and out of
sample, every failure judged, the user's inputs before the ground truth. On Strecha's fountain at half size (its
published cameras; the pairs file of tests/test_gt_suspect.py), with the user's matches written as a text file the
way a user writes them: correct, with their columns swapped, at half resolution, and too few."""

from __future__ import annotations

import numpy as np
import pytest
from test_gt_suspect import first_pair, fountain_half  # noqa: F401 (a fixture)

import fviz
from fviz.diagnose import MIN_EVIDENCE, gt_suspect, gt_suspect_note, heldout_sed
from fviz.geometry import symmetric_epipolar_distance
from fviz.verdicts import GT_SUSPECT, INPUTS, NO_FAILURE, TOO_FEW, failure, pair_verdict


@pytest.fixture(scope="module")
def fountain(fountain_half):  # noqa: F811
    """(pairs file, images folder, the first pair's SIFT matches within 1 px of its ground truth (x_a, x_b))."""
    pairs = fountain_half / "pairs.txt"
    pair = first_pair(pairs, fountain_half)
    result = fviz.inspect_pair(pair, estimators=("magsac",))
    m = result.matches
    good = symmetric_epipolar_distance(pair.F_gt, m.x_a, m.x_b) < 1.0
    return pairs, fountain_half, (m.x_a[good], m.x_b[good])


def _inspect(fountain, tmp_path, x_a, x_b, estimators=("8point", "ransac", "magsac")):
    pairs, images, _ = fountain
    path = tmp_path / "matches.txt"
    np.savetxt(path, np.c_[x_a, x_b], fmt="%.3f")
    pair = fviz.load_pair(pairs=pairs, images=images, index=0, matches=path)
    return pair, fviz.inspect_pair(pair, estimators=estimators)


def test_the_users_correct_matches_draw_no_input_suspicion(fountain, tmp_path):
    x_a, x_b = fountain[2]
    assert len(x_a) > 200
    _, result = _inspect(fountain, tmp_path, x_a, x_b)
    assert result.verdict.kind == NO_FAILURE, result.verdict.line


def test_swapped_columns_are_the_users_mistake_not_the_ground_truths(fountain, tmp_path):
    """x_b y_b x_a y_a: the estimates fit F_gt transposed; the verdict names the swap (the patches around the
    matches correlate far better swapped), never the ground truth, and no estimate's lines become the reference."""
    x_a, x_b = fountain[2]
    pair, result = _inspect(fountain, tmp_path, x_b, x_a)
    v = result.verdict
    assert v.kind == INPUTS and v.detail == "swapped" and "wrong order" in v.text, v.line
    assert not any("gt-suspect" in n for n in result.notes) and gt_suspect_note(pair, result) is None


def test_matches_at_half_resolution_are_the_users_mistake(fountain, tmp_path):
    x_a, x_b = fountain[2]
    _, result = _inspect(fountain, tmp_path, x_a / 2, x_b / 2)
    v = result.verdict
    assert v.kind == INPUTS and v.detail == "scale" and "at 2x their coordinates" in v.text, v.line
    assert "reach 4" in v.text and "images' width" in v.text  # they fill half the images: said


def test_an_exact_fit_through_few_inliers_accuses_nobody(fountain, tmp_path):
    """9 correct matches among 21 (the rest random): RANSAC's consensus is ~9 inliers, fitted exactly (residual
    ~0); no ground-truth suspicion from it (fewer than MIN_EVIDENCE inliers); with 12 matches, too few to judge."""
    x_a, x_b = fountain[2]
    rng = np.random.default_rng(0)
    w, h = 1536, 1024
    noise = rng.uniform((0, 0), (w, h), (12, 2)), rng.uniform((0, 0), (w, h), (12, 2))
    pick = rng.choice(len(x_a), 9, replace=False)
    pair, result = _inspect(fountain, tmp_path, np.r_[x_a[pick], noise[0]], np.r_[x_b[pick], noise[1]])
    assert result.verdict.kind != GT_SUSPECT and gt_suspect_note(pair, result) is None, result.verdict.line
    pair, result = _inspect(fountain, tmp_path, x_a[pick[:6]].tolist() + noise[0][:6].tolist(),
                            x_b[pick[:6]].tolist() + noise[1][:6].tolist())
    v = result.verdict
    assert v.kind == TOO_FEW and "12 matches, fewer than 15" in v.text and "--max-keypoints" in v.text, v.line


def test_held_out_residuals_see_through_an_exact_fit():
    """Through 8 points an 8-point F has zero residual; out of sample it is as far off as it really is. Random
    points: held-out SED of pixels, never ~0; points on a real F: held-out SED at their noise."""
    rng = np.random.default_rng(0)
    x_a, x_b = rng.uniform(0, 1000, (40, 2)), rng.uniform(0, 1000, (40, 2))
    assert np.isnan(heldout_sed(x_a[:MIN_EVIDENCE - 1], x_b[:MIN_EVIDENCE - 1])).all()
    assert np.nanmedian(heldout_sed(x_a, x_b)) > 20
    K = np.array([[700.0, 0, 500], [0, 700, 500], [0, 0, 1]])
    X = np.c_[rng.uniform(-5, 5, (40, 2)), rng.uniform(8, 20, 40)]
    a = X @ K.T
    b = (X + [1.0, 0.1, 0.2]) @ K.T
    x_a, x_b = a[:, :2] / a[:, 2:], b[:, :2] / b[:, 2:] + rng.normal(0, 0.5, (40, 2))
    assert 0.2 < np.nanmedian(heldout_sed(x_a, x_b)) < 2.0


def test_an_estimate_without_a_pose_fails_with_its_epipole_error():
    """No decomposition of its E puts the points in front of both cameras although the pair has cameras and a pose:
    a failure (it was "fine" before), its epipole error the figure; a pose undefined for want of points is not."""
    row = {"name": "8point", "error": None, "metrics": {"sed_median": 1.1, "pose_err_deg": None, "rot_err_deg": None,
                                                         "trans_err_deg": None, "epipole_err_deg": 73.9}}
    assert failure(row) == "no pose: no decomposition puts the points in front of both cameras, epipole 73.9 deg off"
    undefined = {**row, "metrics": {**row["metrics"], "pose_undefined": 1.0, "epipole_err_deg": 2.0}}
    assert failure(undefined) == ""
    far = {**row, "metrics": {"sed_median": 1.1, "epipole_err_deg": 40.0}}  # cameras, no pose: the epipole judges
    assert failure(far) == "epipole 40 deg off"
    rec = {"error": None, "diagnostics": {"n_matches": 900, "static_fraction": 0.0},
           "result": {"n_matches": 900, "n_eval": 800, "eval_threshold_px": 2.0, "F_gt": np.eye(3).tolist(),
                      "match_precision": {"px_prec@1": 0.8, "px_prec@2": 0.9}, "estimators": [row]}}
    v = pair_verdict(rec)
    assert "fine" not in v.text and "8point fails (no pose" in v.text, v.line


def test_gt_suspect_needs_a_held_out_consensus_of_spare_inliers():
    """The evidence of the held-out indoor pairs: RANSAC's 9 inliers 96 px off F_gt and 1e-13 px off its own fit.
    Nothing to judge: 9 inliers are 2 spare; and the fit's own residual is never the comparison."""
    rows = [{"name": "ransac", "error": None, "metrics": {"inlier_ratio": 0.5, "n_inliers": 9, "sed_median": 50.0,
                                                            "epipole_err_deg": 30.0, "rot_err_deg": 20.0}}]
    diag = {"n_matches": 18, "gt_accuracy_px": 0.5, "gt_epipole_distance": 0.3, "baseline_m": 1.0,
            "estimators": {"ransac": {"gt_sed_median_inliers": 96.0, "sed_median_inliers": 1e-13,
                                      "sed_median_heldout": float("nan"), "homography_fraction": 0.3}}}
    assert gt_suspect(diag, rows) is None
    rows[0]["metrics"]["n_inliers"] = 300
    diag["estimators"]["ransac"]["sed_median_heldout"] = 0.4
    assert gt_suspect(diag, rows)["reference"] == "ransac"  # the same misfit, with redundancy: suspect


def test_a_network_is_set_beside_the_straight_ahead_constant():
    """A deep estimate's verdict says whether it beats straight-ahead motion on the same points (measured on every
    pair with cameras, ``-e ahead`` or not), and says so when it does not."""
    row = lambda name, sed: {"name": name, "error": None, "metrics": {"sed_median": sed, "pose_err_deg": 3.0}}  # noqa: E731
    rec = {"error": None, "diagnostics": {"n_matches": 900, "static_fraction": 0.0, "ahead_sed_median": 1.5},
           "result": {"n_matches": 900, "n_eval": 800, "eval_threshold_px": 2.0, "F_gt": np.eye(3).tolist(),
                      "match_precision": {"px_prec@1": 0.8, "px_prec@2": 0.9},
                      "estimators": [row("magsac", 0.3), row("deep", 1.6)]}}
    v = pair_verdict(rec)
    assert v.kind == NO_FAILURE and v.text.endswith("; deep 1.6 px vs ahead 1.5 px sed_median: no better than the constant")
    rec["result"]["estimators"][1] = row("deep", 0.9)
    assert pair_verdict(rec).text.endswith("deep 0.9 px vs ahead 1.5 px sed_median: beats the constant")
