"""A run's figures end to end on the real samples, through the real command line: the standard figures of a run
(summary.json, summary.md, the table eval prints), the baselines that have not seen the labels, triage's
estimator findings and tags on data built to trigger them, and triage reusing any finished run."""

import json
import math

import cv2
import numpy as np
import pytest
from cli_util import assert_one_line_error, read_csv, run_fviz

from fviz.geometry import normalize, pose_auc

pytestmark = pytest.mark.kitti

SMALL = ("--max-keypoints", "400", "--no-progress", "--workers", "1")
USER_ESTIMATORS = '''
import cv2
import numpy as np

from fviz.geometry import fundamental_from_motion


def frozen(pair, x_a, x_b):
    """A plausible F of slightly turning forward motion, the same whatever the images."""
    R = cv2.Rodrigues(np.array([0.0, 0.01, 0.0]))[0]
    return fundamental_from_motion(pair.K_a, pair.K_b, R, np.array([0.05, 0.0, 1.0]))


def odd(pair, x_a, x_b):
    """OpenCV's 8-point that fails on pairs starting at an odd frame."""
    if pair.id.frame_a % 2:
        raise RuntimeError("odd frame")
    return cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)[0]
'''


def seq00(kitti_root, frames):
    return ("--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", frames)


def ok(proc):
    assert proc.returncode == 0, proc.stderr
    return proc


@pytest.fixture(scope="module")
def run(kitti_root, tmp_path_factory):
    """Frames 0..7 of sequence 00 with MAGSAC, the baselines and two user estimators."""
    tmp = tmp_path_factory.mktemp("figures")
    (tmp / "userest.py").write_text(USER_ESTIMATORS)
    out = tmp / "run"
    proc = ok(run_fviz("eval", *seq00(kitti_root, "0:8"), "-e", "magsac", "-e", "userest:frozen", "-e", "userest:odd",
                       "-e", "ahead", "-e", "mean:01", "-e", "oracle-mean", *SMALL, "--out-dir", out, cwd=tmp, timeout=300))
    return tmp, out, proc


def per_estimator(out, name):
    return [r for r in read_csv(out / "metrics.csv") if r["estimator"] == name]


def value(row, key):
    return math.nan if row["error"] or row[key] == "" else float(row[key])


def test_summary_json_holds_the_standard_figures(run):
    _, out, _ = run
    doc = json.loads((out / "summary.json").read_text())
    assert list(doc["estimators"]) == ["gt", "magsac", "frozen", "odd", "ahead", "mean-01", "oracle-mean"]
    for name, f in doc["estimators"].items():
        rows = per_estimator(out, name)
        assert f["pairs"] == len(rows) == 7
        assert f["errors"] == sum(bool(r["error"]) for r in rows)
        # fails (sed_median > 2 px, or no value): compare's count of the same pairs (fviz.verdicts)
        assert f["fails"] == sum(bool(r["error"]) or not value(r, "sed_median") <= 2.0 for r in rows)
        ok_rows = [r for r in rows if not r["error"]]
        assert f["sed_median"] == pytest.approx(np.median([float(r["sed_median"]) for r in ok_rows]))
        assert f["sampson_median"] == pytest.approx(np.median([float(r["sampson_median"]) for r in ok_rows]))
        # FM-Bench's recall: a failure is a miss
        assert f["nsgd_recall"] == pytest.approx(sum(value(r, "nsgd") < 0.05 for r in rows) / 7)
        assert f["oracle"] == (name == "oracle-mean")
    assert doc["estimators"]["gt"]["pose_auc"] == {"5": 1.0, "10": 1.0, "20": 1.0}
    assert doc["estimators"]["odd"]["errors"] == 3  # pairs starting at frames 1, 3, 5 of 0..6


def test_failures_count_as_infinite_pose_error(run):
    """With k of n pairs failed the recall curve is the successful pairs' scaled by (n - k) / n."""
    _, out, _ = run
    rows = per_estimator(out, "odd")
    errors = [float(r["pose_err_deg"]) for r in rows if not r["error"]]
    doc = json.loads((out / "summary.json").read_text())["estimators"]["odd"]["pose_auc"]
    expected = [a * len(errors) / len(rows) for a in pose_auc(errors)]
    assert list(doc.values()) == pytest.approx(expected)
    assert pose_auc([float(r["pose_err_deg"]) for r in per_estimator(out, "magsac")]) == pytest.approx(
        list(json.loads((out / "summary.json").read_text())["estimators"]["magsac"]["pose_auc"].values()))


def test_eval_prints_the_table_and_summary_md_explains_it(run):
    _, out, proc = run
    for word in ("AUC@5°", "AUC@20°", "NSGD recall", "med SED px", "oracle-mean (oracle)", "mean-01", "3/7"):
        assert word in proc.stdout
    md = (out / "summary.md").read_text()
    assert "## Standard figures" in md and "oracle-mean (*oracle*)" in md and "glue-factory" in md
    assert "Under ETR" in md and "depend on the normalization" in md
    assert "### f_dist" not in md


def test_ahead_is_straight_ahead_motion_from_the_cameras(run, odometry):
    _, out, _ = run
    doc = json.loads((out / "results.jsonl").read_text().splitlines()[0])
    F = np.array(next(e["F"] for e in doc["result"]["estimators"] if e["name"] == "ahead"))
    K = np.array(doc["result"]["pair"]["K_a"])
    Kinv = np.linalg.inv(K)
    expected = Kinv.T @ np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 0]]) @ Kinv
    np.testing.assert_allclose(normalize(F, "fbn"), normalize(expected, "fbn"), atol=1e-12)


def test_mean_baseline_is_the_mean_gt_of_the_named_sequence(run, kitti_root):
    from fviz.data.kitti import open_dataset

    _, out, _ = run
    ds = open_dataset(kitti_root, sequence="01")
    Fs = [normalize(ds.ground_truth(ds.pair_id(f, "temporal", 1, None))[4], "fbn") for f in range(ds.num_frames - 1)]
    acc = sum(F if np.sum(F * Fs[0]) >= 0 else -F for F in Fs)
    U, S, Vt = np.linalg.svd(acc)
    expected = normalize(U @ np.diag([S[0], S[1], 0.0]) @ Vt, "fbn")
    stored = np.array(json.loads((out / "run.json").read_text())["baseline_F"]["mean:01"]).reshape(3, 3)
    np.testing.assert_allclose(stored, expected, atol=1e-9)


def test_triage_findings_flag_the_constant_estimators_only(run):
    """`ignores-input` on a user module:function that returns a constant (and on the baselines, constant by
    design), never on MAGSAC; triage reuses the finished eval run."""
    tmp, out, _ = run
    before = (out / "results.jsonl").read_bytes()
    proc = ok(run_fviz("triage", "--out-dir", out, "--top", "3", "--no-progress", cwd=tmp, timeout=300))
    assert (out / "results.jsonl").read_bytes() == before and "0 evaluated now" in proc.stderr
    md = (out / "triage.md").read_text()
    findings, pairs = md.split("## Pairs")
    flagged = {line.split("|")[1].strip().split(" ")[0]: line.split("|")[6] for line in findings.splitlines()
               if line.startswith("| ") and not line.startswith("| estimator")}
    assert "ignores-input" in flagged["frozen"] and "ignores-input" in flagged["ahead"]
    assert "ignores-input" in flagged["oracle-mean"] and "ignores-input" in flagged["mean-01"]
    # MAGSAC's epipole jitters 1.5-1.9 deg against the truth's 0.27 deg over these 7 pairs (400-800 keypoints): its
    # bootstrap interval spans 0 or not by chance (it reached below 0.1 once fviz's SIFT moved to the pixel-centre
    # convention), so the flag says "not told apart", never the constants' zero spread
    assert "worse-than-baseline" not in flagged["magsac"]
    magsac = next(line for line in findings.splitlines() if line.startswith("| magsac "))
    assert float(magsac.split("|")[4].split()[0]) > 0.5  # its epipole spread: it reads its input
    assert "ignores-input" not in flagged["odd"]  # 4 successful pairs: too few to judge
    assert "frozen: ignores-input" in proc.stdout
    # ranked by the first estimator the eval run named, and triage.md says so
    assert "Ranked by `sed_median` of `magsac` (the first estimator named" in pairs
    assert findings.index("## Estimators over the run") < len(findings)


def test_triage_by_any_estimator_and_no_ranking_by_f_dist(run):
    tmp, out, _ = run
    ok(run_fviz("triage", "--out-dir", out, "--by", "frozen", "--metric", "pose_err_deg", "--top", "2",
                "--no-progress", cwd=tmp, timeout=300))
    assert "Ranked by `pose_err_deg` of `frozen`, worst first" in (out / "triage.md").read_text()
    errors = {r["name"]: float(r["pose_err_deg"]) for r in per_estimator(out, "frozen")}
    assert f"| 0 | `{max(errors, key=errors.get)}` |" in (out / "triage.md").read_text()
    assert_one_line_error(run_fviz("triage", "--out-dir", out, "--metric", "f_dist", "--no-progress", cwd=tmp),
                          2, "--metric f_dist", "sed_median")


@pytest.mark.parametrize("spec, fragment", [("constant", "oracle-mean"), ("mean:00", "oracle-mean"),
                                            ("mean:", "mean:SEQ")])
def test_baseline_names_are_checked(kitti_root, tmp_path, spec, fragment):
    r = run_fviz("eval", *seq00(kitti_root, "0:3"), "-e", spec, "--no-progress", "--out-dir", tmp_path / "run")
    assert_one_line_error(r, 2, f"--estimator {spec}", fragment)


# ------------------------------------------------------------------------------ triage reuses any finished run


def test_readme_eval_then_triage_reuses_the_run(kitti_root, tmp_path):
    """The README's flow, then the same flags again, then a merged run."""
    out = tmp_path / "seq00"
    est = ("-e", "8point", "-e", "ransac", "-e", "magsac")
    ok(run_fviz("eval", *seq00(kitti_root, "0:6"), *est, *SMALL, "--out-dir", out, timeout=300))
    before = (out / "results.jsonl").read_bytes()
    for extra in ((), (*seq00(kitti_root, "0:6"), *est, *SMALL)):
        proc = ok(run_fviz("triage", *extra, "--out-dir", out, "--no-progress", timeout=300))
        assert "5 pairs (5 already done, 0 evaluated now" in proc.stderr
        assert (out / "results.jsonl").read_bytes() == before
    # an estimator the run lacks: added, the others kept
    ok(run_fviz("triage", "-e", "ahead", "--out-dir", out, "--no-progress", timeout=300))
    assert json.loads((out / "run.json").read_text())["options"]["names"] == ["8point", "ransac", "magsac", "ahead"]
    assert "Ranked by `sed_median` of `ahead`" in (out / "triage.md").read_text()
    # shards merged into one run
    for i in (0, 1):
        ok(run_fviz("eval", *seq00(kitti_root, "0:6"), *est, *SMALL, "--shard", f"{i}/2", "--out-dir", tmp_path / f"s{i}"))
    ok(run_fviz("merge", tmp_path / "s0", tmp_path / "s1", "--out-dir", tmp_path / "merged"))
    proc = ok(run_fviz("triage", "--out-dir", tmp_path / "merged", "--no-progress", timeout=300))
    assert "0 evaluated now" in proc.stderr


# ------------------------------------------------------------------------------ tags on data built for them


def copied_layout(root, kitti_root, frames, translation_deg=0.0, identical=False):
    """Sequence 00 frames 0..frames-1 under ``root``: images symlinked (all to frame 0 when ``identical``),
    poses with the trajectory turned by ``translation_deg`` about the vertical axis while every camera keeps
    its orientation: each relative translation direction is then off by that angle."""
    src = kitti_root / "odometry" / "dataset"
    seq = root / "odometry" / "dataset" / "sequences" / "00"
    (seq / "image_0").mkdir(parents=True)
    (root / "odometry" / "dataset" / "poses").mkdir(parents=True)
    (seq / "calib.txt").write_text((src / "sequences" / "00" / "calib.txt").read_text())
    for f in range(frames):
        (seq / "image_0" / f"{f:06d}.png").symlink_to(src / "sequences" / "00" / "image_0" / f"{0 if identical else f:06d}.png")
    T = np.loadtxt(src / "poses" / "00.txt")[:frames].reshape(-1, 3, 4)
    Q = cv2.Rodrigues(np.array([0.0, np.radians(translation_deg), 0.0]))[0]
    T[:, :, 3] = (T[:, :, 3] - T[0, :, 3]) @ Q.T + T[0, :, 3]
    np.savetxt(root / "odometry" / "dataset" / "poses" / "00.txt", T.reshape(-1, 12))
    return root


def triage_tags(root, out, frames, keypoints=400):
    ok(run_fviz("triage", "--kitti-root", root, "--sequence", "00", "--pair", "temporal", "--frames", frames,
                "-e", "magsac", "-e", "ransac", *SMALL, "--max-keypoints", keypoints, "--out-dir", out, timeout=300))
    from fviz.triage import rank_pairs

    return {r.key: [t for t, _ in r.tags] for r in rank_pairs(
        [json.loads(line) for line in open(out / "results.jsonl")], "magsac", "sed_median")}


def test_gt_suspect_holds_on_poses_13_degrees_off(kitti_root, tmp_path):
    bad = copied_layout(tmp_path / "bad", kitti_root, 7, translation_deg=13.0)
    good = copied_layout(tmp_path / "good", kitti_root, 7)
    # the perturbation is what it says: every relative translation direction is 13 deg off
    from fviz.data.kitti import open_dataset
    from fviz.geometry import translation_error_deg

    b, g = open_dataset(bad, sequence="00"), open_dataset(good, sequence="00")
    for f in range(6):
        pid = g.pair_id(f, "temporal", 1, None)
        assert translation_error_deg(b.ground_truth(pid)[3], g.ground_truth(pid)[3]) == pytest.approx(13.0, abs=0.5)
    # 2000 keypoints: the robust estimators' directions are then 9-15 deg off with these poses, 1.6-4.4 deg with
    # the official ones (with 400, one MAGSAC F lands 90 deg off: the other tight fit keeps it from accusing the GT)
    assert all("gt-suspect" in tags for tags in triage_tags(bad, tmp_path / "r_bad", "0:7", 2000).values())
    assert not any("gt-suspect" in tags for tags in triage_tags(good, tmp_path / "r_good", "0:7", 2000).values())
    assert not any("gt-suspect" in tags for tags in triage_tags(good, tmp_path / "r_400", "0:7", 400).values())


def test_identical_images_are_degenerate(kitti_root, tmp_path):
    """Frame 0 twice: RANSAC and MAGSAC fit it to ~1e-13 px with every match an inlier; the tag says why."""
    root = copied_layout(tmp_path / "same", kitti_root, 3, identical=True)
    tags = triage_tags(root, tmp_path / "r", "0:3")
    assert all("degenerate" in t for t in tags.values())
    rows = per_estimator(tmp_path / "r", "magsac")
    assert all(float(r["sed_median"]) < 1e-6 for r in rows)
    normal = triage_tags(kitti_root, tmp_path / "r_normal", "0:3")
    assert not any("degenerate" in t for t in normal.values())


def test_results_jsonl_holds_every_pose_and_reads_back(run):
    from fviz.run import read_config, result_from_record

    _, out, _ = run
    rec = json.loads((out / "results.jsonl").read_text().splitlines()[0])
    result = result_from_record(rec, read_config(out))
    for doc, est in zip(rec["result"]["estimators"], result.estimators):
        R, t = np.array(doc["R"]), np.array(doc["t"])
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
        assert np.linalg.norm(t) == pytest.approx(1.0)
        np.testing.assert_array_equal(est.R, R)
        np.testing.assert_array_equal(est.t, t)
