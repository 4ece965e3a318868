"""Runs of a user's pairs (KITTI frames given as a pairs file, with their poses or names only): a pair whose line,
ground-truth matches or COLMAP pose is edited is evaluated again on resume, the standard figures count only the pairs
with ground truth, a run without any says so (no oracle, no mean F) instead of failing every pair, and seven matches
run the estimators that need seven. Through the real ``fviz`` in a subprocess."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from cli_util import assert_one_line_error, read_csv, run_fviz

FAST = ("--max-keypoints", "400", "--workers", "1", "--no-progress")
VOLATILE = {"seconds"}



def ok(*args, **kw):
    r = run_fviz(*args, **kw)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return r


def lines(path):
    return [json.loads(line) for line in Path(path).read_text().splitlines()]


def stable(rows):
    return [{k: v for k, v in r.items() if k not in VOLATILE} for r in rows]


# ------------------------------------------------------------------------------ KITTI pairs as a user's pairs file


def kitti_pairs(kitti_root):
    """(image folder, [temporal 3->4 line, stereo 0 line] with poses, their names-only versions, stereo T)."""
    seq = kitti_root / "odometry" / "dataset" / "sequences" / "00"
    calib = {l.split(":")[0]: np.array(l.split()[1:], float).reshape(3, 4)
             for l in (seq / "calib.txt").read_text().splitlines() if ":" in l}
    poses = np.loadtxt(kitti_root / "odometry" / "dataset" / "poses" / "00.txt").reshape(-1, 3, 4)
    K0 = calib["P0"][:, :3]
    to4 = lambda M: np.vstack([M, [0, 0, 0, 1]])  # noqa: E731
    T_stereo = np.eye(4)
    T_stereo[:3, 3] = np.linalg.solve(calib["P1"][:, :3], calib["P1"][:, 3])
    T_temporal = np.linalg.inv(to4(poses[4])) @ to4(poses[3])
    names = [("image_0/000003.png", "image_0/000004.png"), ("image_0/000000.png", "image_1/000000.png")]
    full = [f"{a} {b} 0 0 " + " ".join(repr(float(v)) for v in [*K0.ravel(), *calib["P0" if i == 0 else "P1"][:, :3].ravel(), *T.ravel()])
            for i, (T, (a, b)) in enumerate(zip((T_temporal, T_stereo), names))]
    return seq, full, [f"{a} {b}" for a, b in names], K0, T_temporal, T_stereo


def line_F(K0, K1, T):
    """F of a pairs line, written out: K1^-T [t]x R K0^-1, unit norm."""
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    F = np.linalg.inv(K1).T @ tx @ R @ np.linalg.inv(K0)
    return F / np.linalg.norm(F)


def same_up_to_sign(A, B, tol=1e-6):
    A, B = np.asarray(A, float), np.asarray(B, float)
    return min(np.abs(A - B).max(), np.abs(A + B).max()) < tol


def auc_one(err, t):
    """LightGlue's pose AUC of one pair's error at threshold t, written out."""
    return (t - err / 2) / t if err < t else 0.0


# ------------------------------------------------------------------------------ edited inputs evaluated again


def test_resume_after_a_pairs_line_was_edited_evaluates_that_pair_again(kitti_root, tmp_path):
    seq, full, _, K0, T_temporal, T_stereo = kitti_pairs(kitti_root)
    pairs, run = tmp_path / "pairs.txt", tmp_path / "run"
    pairs.write_text("\n".join(full) + "\n")
    ok("eval", "--pairs", pairs, "--images", seq, "-e", "8point", *FAST, "--out-dir", run)
    before = lines(run / "results.jsonl")
    # the user corrects the pose of line 0 (another motion), then adds an estimator
    T_new = T_temporal.copy()
    T_new[:3, 3] = [0.3, 0.0, -0.9]
    fields = full[0].split()
    fields[22:] = [repr(float(v)) for v in T_new.ravel()]
    pairs.write_text(" ".join(fields) + "\n" + full[1] + "\n")
    r = ok("eval", "--resume", "--pairs", pairs, "--images", seq, "-e", "8point", "-e", "magsac", *FAST, "--out-dir", run)
    assert "1 records ignored (1 made with other settings or inputs" in r.stderr, r.stderr
    latest = {rec["index"]: rec for rec in lines(run / "results.jsonl")}
    assert same_up_to_sign(latest[0]["result"]["F_gt"], line_F(K0, K0, T_new))
    assert not same_up_to_sign(before[0]["result"]["F_gt"], latest[0]["result"]["F_gt"], 1e-3)
    # every estimator of the edited pair is scored against the new pose: as a fresh run on the edited file
    ok("eval", "--pairs", pairs, "--images", seq, "-e", "8point", "-e", "magsac", *FAST, "--out-dir", tmp_path / "fresh")
    rows = [r for r in read_csv(run / "metrics.csv") if r["index"] == "0"]
    fresh = [r for r in read_csv(tmp_path / "fresh" / "metrics.csv") if r["index"] == "0"]
    assert stable(rows) == stable(fresh)
    # the untouched line kept its record (8point not computed again)
    assert latest[1]["result"]["estimators"][:2] == before[1]["result"]["estimators"][:2]


def test_resume_after_gt_matches_were_edited_evaluates_again(kitti_root, tmp_path):
    """--gt-matches (one file per pair in a folder): editing one pair's file re-evaluates that pair only."""
    seq, _, names, *_ = kitti_pairs(kitti_root)
    pairs, gt, run = tmp_path / "pairs.txt", tmp_path / "gt", tmp_path / "run"
    pairs.write_text("\n".join(names) + "\n")
    gt.mkdir()
    rng = np.random.default_rng(0)
    for a, b in (n.split() for n in names):
        x = rng.uniform([10, 10], [1200, 360], (40, 2))
        (gt / f"{Path(a).stem}_{Path(b).stem}.txt").write_text("".join(f"{u} {v} {u + 5} {v}\n" for u, v in x))
    ok("eval", "--pairs", pairs, "--images", seq, "--gt-matches", gt, "-e", "8point", *FAST, "--out-dir", run)
    edited = gt / "000003_000004.txt"
    edited.write_text("".join(f"{u} {v} {u} {v + 4}\n" for u, v in rng.uniform([10, 10], [1200, 360], (40, 2))))
    r = ok("eval", "--resume", "--pairs", pairs, "--images", seq, "--gt-matches", gt, "-e", "8point", *FAST, "--out-dir", run)
    assert "1 already done, 1 evaluated now" in r.stderr, r.stderr


def test_standard_figures_count_only_pairs_with_ground_truth(kitti_root, tmp_path):
    seq, full, names, *_ = kitti_pairs(kitti_root)
    pairs, run = tmp_path / "pairs.txt", tmp_path / "run"
    pairs.write_text(full[0] + "\n" + names[1] + "\n")  # a pose, then names only
    ok("eval", "--pairs", pairs, "--images", seq, "-e", "magsac", *FAST, "--out-dir", run)
    row = next(r for r in read_csv(run / "metrics.csv") if r["estimator"] == "magsac" and r["index"] == "0")
    err, nsgd = float(row["pose_err_deg"]), float(row["nsgd"])
    f = json.loads((run / "summary.json").read_text())["estimators"]["magsac"]
    for t in ("5", "10", "20"):
        assert f["pose_auc"][t] == pytest.approx(auc_one(err, float(t)), abs=1e-9)
    from fviz.geometry import NSGD_RECALL_THRESHOLD

    assert f["nsgd_recall"] == (1.0 if nsgd < NSGD_RECALL_THRESHOLD else 0.0)
    assert (f["pose_pairs"], f["gt_pairs"], f["pairs"]) == (1, 1, 2)
    assert "pose AUC over 1 and NSGD recall over 1 of 2 pairs" in (run / "summary.md").read_text()
    from fviz.table import run_figures

    assert run_figures(run)["magsac"]["pose_auc"]["20"] == pytest.approx(auc_one(err, 20.0), abs=1e-9)
    assert f"| {auc_one(err, 20.0):.4g} |" in ok("table", run).stdout  # the table prints the same figure


def test_a_record_fingerprint_follows_an_edited_colmap_pose(tmp_path):
    """The fingerprint of a COLMAP pair covers its cameras and poses: an edited images.txt is another input."""
    from sources_util import fountain

    from fviz.run.config import RunConfig, Selection
    from fviz.estimators.options import EstimatorOptions

    model = tmp_path / "colmap"
    shutil.copytree(fountain() / "colmap", model)

    def prints():
        config = RunConfig(Selection(colmap=str(model), images=str(fountain() / "images")), EstimatorOptions(names=("8point",)))
        source = config.selection.source()
        return [config.fingerprint(pid.to_dict()) for pid in source.pair_ids()]

    before = prints()
    text = (model / "images.txt").read_text().splitlines()
    i = next(n for n, line in enumerate(text) if line.startswith("2 "))
    fields = text[i].split()
    fields[5] = repr(float(fields[5]) + 0.5)  # image 2 (0001.jpg) moved by half a metre
    text[i] = " ".join(fields)
    (model / "images.txt").write_text("\n".join(text) + "\n")
    after = prints()
    changed = [a != b for a, b in zip(before, after)]
    assert any(changed) and not all(changed)  # the pairs of image 2 only


# ------------------------------------------------------------------------------ runs without ground truth


@pytest.fixture(scope="module")
def no_gt_run(kitti_root, tmp_path_factory):
    """(images, names-only pairs file, a finished 8point run of it)."""
    seq, _, names, *_ = kitti_pairs(kitti_root)
    base = tmp_path_factory.mktemp("nogt")
    pairs = base / "names.txt"
    pairs.write_text("\n".join(names) + "\n")
    ok("eval", "--pairs", pairs, "--images", seq, "-e", "8point", *FAST, "--out-dir", base / "run")
    return seq, pairs, base / "run"


@pytest.mark.parametrize("command", ["eval", "triage"])
def test_a_new_estimator_on_a_run_without_ground_truth(no_gt_run, tmp_path, command):
    _, _, done = no_gt_run
    run = tmp_path / "run"
    shutil.copytree(done, run)
    extra = ("--resume",) if command == "eval" else ()
    ok(command, *extra, "--out-dir", run, "-e", "8point", "-e", "ransac", *FAST)
    names = {r["estimator"] for r in read_csv(run / "metrics.csv")}
    assert {"8point", "ransac"} <= names and "gt" not in names


def test_oracle_mean_without_ground_truth_is_one_line(no_gt_run, tmp_path):
    seq, pairs, _ = no_gt_run
    r = run_fviz("eval", "--pairs", pairs, "--images", seq, "-e", "oracle-mean", *FAST, "--out-dir", tmp_path / "r")
    assert_one_line_error(r, 2, "--estimator oracle-mean: no pair of its selection has a ground-truth F", "has no ground truth")


def test_mean_of_a_sequence_with_a_pairs_file_is_one_line(no_gt_run, tmp_path):
    seq, pairs, _ = no_gt_run
    r = run_fviz("eval", "--pairs", pairs, "--images", seq, "-e", "mean:01", *FAST, "--out-dir", tmp_path / "r")
    assert_one_line_error(r, 2, "--estimator mean:01: mean:SEQ averages the ground truth of other KITTI sequences",
                          "a --pairs run has no sequence to average")


def test_a_threshold_sweep_without_ground_truth_leaves_the_oracle_out_and_says_why(no_gt_run, tmp_path):
    seq, pairs, _ = no_gt_run
    run = tmp_path / "r"
    r = ok("eval", "--pairs", pairs, "--images", seq, "-e", "magsac", "--threshold", "sweep", *FAST, "--out-dir", run)
    assert "note: magsac@oracle left out: the per-pair oracle picks each pair's threshold by its ground truth, and no " \
           "pair of the selection has one" in r.stderr  # a note, not a failure on every pair
    rows = read_csv(run / "metrics.csv")
    assert not [row for row in rows if row["estimator"] == "magsac-th-oracle"] and "numpy" not in r.stderr
    assert {row["estimator"] for row in rows} >= {"magsac-th1"}
    assert all(not row["error"] for row in rows if row["estimator"] == "magsac-th1")


# ------------------------------------------------------------------------------ too few matches


def test_inspect_with_seven_matches_runs_the_estimators_that_need_seven(kitti_root, tmp_path):
    seq, _, _, K0, T_temporal, _ = kitti_pairs(kitti_root)
    rng = np.random.default_rng(3)
    x_a = rng.uniform([100, 60], [1100, 320], (7, 2))
    X = np.c_[x_a, np.ones(7)] @ np.linalg.inv(K0).T * rng.uniform(6, 40, (7, 1))
    x = (X @ T_temporal[:3, :3].T + T_temporal[:3, 3]) @ K0.T
    x_b = x[:, :2] / x[:, 2:]
    matches = tmp_path / "seven.txt"
    matches.write_text("".join(f"{a[0]} {a[1]} {b[0]} {b[1]}\n" for a, b in zip(x_a, x_b)))
    args = ("inspect", "pair", "--image-a", seq / "image_0" / "000003.png", "--image-b", seq / "image_0" / "000004.png",
            "--matches", matches, "--out", tmp_path / "p.rrd")
    r = run_fviz(*args, "-e", "7point")
    assert r.returncode == 0 and "needed" not in r.stderr, r.stderr
    both = run_fviz(*args, "-e", "7point", "-e", "8point")  # 8point fails on its own, the pair does not
    assert both.returncode == 1 and "error: estimator 8point" in both.stderr and "needed); recorded" not in both.stderr, both.stderr
    six = tmp_path / "six.txt"
    six.write_text("".join(matches.read_text().splitlines(keepends=True)[:6]))
    r6 = run_fviz(*args[:-4], "--matches", six, "--out", tmp_path / "p6.rrd", "-e", "7point")
    assert r6.returncode == 2 and "only 6 matches" in r6.stderr and "Traceback" not in r6.stderr, r6.stderr
