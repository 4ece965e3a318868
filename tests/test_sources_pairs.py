"""Pairs of a user: two image files (with or without ground truth) and SuperGlue/LightGlue pairs files,
on the real fountain-P11 scene and on KITTI written as a pairs line by the test."""

import json

import numpy as np
import pytest
from cli_util import assert_one_line_error, run_fviz
from sources_util import FAST, GT_METRICS, closed_form_F, fountain, same_up_to_sign, strecha_camera, strecha_projection

from fviz.record.reader import blueprint_tabs, text
from fviz.record.summary import read_recording
from fviz.record import layout as L


def inspect_json(*args):
    proc = run_fviz("inspect", "pair", *args, "--json", timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout), proc


@pytest.fixture(scope="module")
def fountain_pair(tmp_path_factory):
    d = fountain()
    out = tmp_path_factory.mktemp("pairs") / "p.rrd"
    doc, _ = inspect_json("--pairs", d / "pairs_with_gt.txt", "--images", d / "images", "--index", "0", *FAST, "--out", out)
    return doc, out


def test_pairs_line_gt_is_the_closed_form_F_of_the_published_cameras(fountain_pair):
    doc, _ = fountain_pair
    assert doc["pair"]["image_a"] == "0000.jpg" and doc["pair"]["image_b"] == "0001.jpg"
    assert doc["ground_truth"] == "pose" and doc["eval_points"] == "near-gt"
    F_ref = closed_form_F(strecha_projection("0000.jpg"), strecha_projection("0001.jpg"))
    assert same_up_to_sign(doc["F_gt"], F_ref, 1e-6)
    rows = {e["name"]: e["metrics"] for e in doc["estimators"]}
    # the README's measurement: SIFT inliers sit ~0.2-0.3 px from this ground truth at full resolution
    assert rows["gt"]["sed_median"] < 0.5 and doc["n_eval"] > 100
    assert rows["magsac"]["pose_err_deg"] < 2.0 and rows["8point"]["sed_median"] > rows["magsac"]["sed_median"]


def test_two_images_with_K_and_pose_give_the_pairs_line_result(fountain_pair, tmp_path):
    d = fountain()
    doc_pairs, _ = fountain_pair
    K_a, R_a, C_a = strecha_camera("0000.jpg")
    K_b, R_b, C_b = strecha_camera("0001.jpg")
    # world->camera: x_c = R^T (X - C); a->b: R_ab = R_b^T R_a, t_ab = R_b^T (C_a - C_b)
    R_ab, t_ab = R_b.T @ R_a, R_b.T @ (C_a - C_b)
    T = np.c_[R_ab, t_ab].ravel()
    (tmp_path / "T.txt").write_text(" ".join(repr(float(v)) for v in T))
    fmt = lambda K: ",".join(repr(float(v)) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))  # noqa: E731
    doc, _ = inspect_json("--image-a", d / "images" / "0000.jpg", "--image-b", d / "images" / "0001.jpg",
                          "--K-a", fmt(K_a), "--K-b", fmt(K_b), "--T-ab", tmp_path / "T.txt", *FAST, "--out", tmp_path / "x.rrd")
    assert doc["ground_truth"] == "pose"
    assert np.abs(np.array(doc["F_gt"]) - np.array(doc_pairs["F_gt"])).max() < 1e-6
    ours = {e["name"]: e["metrics"] for e in doc["estimators"]}
    theirs = {e["name"]: e["metrics"] for e in doc_pairs["estimators"]}
    # the pairs file rounds the published numbers: F agrees to 1e-6, the evaluation matches but for borderline ones
    assert abs(doc["n_eval"] - doc_pairs["n_eval"]) <= 3
    assert ours["gt"]["sed_median"] == pytest.approx(theirs["gt"]["sed_median"], rel=2e-2)


def test_two_images_without_ground_truth(tmp_path):
    d = fountain()
    out = tmp_path / "nogt.rrd"
    doc, proc = inspect_json("--image-a", d / "images" / "0002.jpg", "--image-b", d / "images" / "0003.jpg", *FAST,
                             "--out", out)
    assert doc["F_gt"] is None and doc["ground_truth"] == "none" and doc["eval_points"] == "all-matches"
    assert doc["n_eval"] == doc["n_matches"] > 50
    names = [e["name"] for e in doc["estimators"]]
    assert "gt" not in names and names == ["8point", "ransac", "magsac"]
    for e in doc["estimators"]:
        assert not set(GT_METRICS) & set(e["metrics"]), e["metrics"].keys()
        assert all(v is not None for v in e["metrics"].values())  # absent, not NaN-filled
    ag = doc["agreement"]
    M = np.array(ag["matrix"])
    assert ag["names"] == names and np.allclose(M, M.T) and np.all(np.diag(M) == 0)
    # the two robust estimators agree with each other far better than with the 8-point fit on all matches
    assert M[1, 2] < M[0, 1] and M[1, 2] < M[0, 2]
    # agreement_nsgd: the NSGD to the closest other F (a median over the others hid that two agree); the groups
    # join the estimators whose NSGD is under the threshold
    for i, e in enumerate(doc["estimators"]):
        assert e["metrics"]["agreement_nsgd"] == pytest.approx(np.delete(M[i], i).min())
    assert ag["threshold"] == 0.05 and sorted(n for g in ag["groups"] for n in g) == sorted(names)
    # chained through 8point
    assert any({"ransac", "magsac"} <= set(g) for g in ag["groups"]) == (M[1, 2] < 0.05 or max(M[0, 1], M[0, 2]) < 0.05)
    assert "no ground truth" in proc.stderr
    summary = text(out, L.SUMMARY)[0]
    assert "no ground truth" in summary and "NSGD between the estimators" in summary
    rec = read_recording(out)
    assert set(rec.items[0].metrics["agreement_nsgd"]) == set(names)
    assert "nsgd" not in rec.items[0].metrics
    # the overview shows the last estimator's keypoints and lines (there are no ground-truth ones)
    overview = blueprint_tabs(out)["overview"]
    assert f"+ {L.matches('magsac')}" in overview and not any("/gt" in q for q in overview)


def test_kitti_pair_as_a_pairs_line_matches_kitti_root(kitti_root, tmp_path):
    """The test writes KITTI's calibration and poses as pairs lines itself: same F_gt and metrics to 1e-9."""
    seq = kitti_root / "odometry" / "dataset" / "sequences" / "00"
    calib = {l.split(":")[0]: np.array(l.split()[1:], float).reshape(3, 4)
             for l in (seq / "calib.txt").read_text().splitlines() if ":" in l}
    poses = np.loadtxt(kitti_root / "odometry" / "dataset" / "poses" / "00.txt").reshape(-1, 3, 4)
    K0 = calib["P0"][:, :3]
    t1 = np.linalg.solve(calib["P1"][:, :3], calib["P1"][:, 3])
    to4 = lambda M: np.vstack([M, [0, 0, 0, 1]])  # noqa: E731
    T_stereo = np.eye(4)
    T_stereo[:3, 3] = t1
    T_temporal = np.linalg.inv(to4(poses[4])) @ to4(poses[3])  # camera 0 at frame 3 -> at frame 4
    lines = []
    for T, (a, b) in ((T_stereo, ("image_0/000000.png", "image_1/000000.png")), (T_temporal, ("image_0/000003.png", "image_0/000004.png"))):
        nums = [*K0.ravel(), *calib["P1" if "image_1" in b else "P0"][:, :3].ravel(), *T.ravel()]
        lines.append(f"{a} {b} 0 0 " + " ".join(repr(float(v)) for v in nums))
    (tmp_path / "kitti_pairs.txt").write_text("\n".join(lines) + "\n")
    for index, kind, frame in ((0, "stereo", 0), (1, "temporal", 3)):
        ours, _ = inspect_json("--pairs", tmp_path / "kitti_pairs.txt", "--images", seq, "--index", index,
                               "--out", tmp_path / f"p{index}.rrd", "--max-keypoints", "800")
        ref, _ = inspect_json("--kitti-root", kitti_root, "--sequence", "00", "--pair", kind, "--frame", frame,
                              "--out", tmp_path / f"k{index}.rrd", "--max-keypoints", "800")
        assert np.abs(np.array(ours["F_gt"]) - np.array(ref["F_gt"])).max() < 1e-9
        assert ours["n_matches"] == ref["n_matches"] and ours["n_eval"] == ref["n_eval"]
        for a, b in zip(ours["estimators"], ref["estimators"]):
            assert a["name"] == b["name"] and a["metrics"].keys() == b["metrics"].keys()
            for k, v in a["metrics"].items():
                w = b["metrics"][k]
                assert (v is None and w is None) or abs(v - w) <= 1e-9 * max(1.0, abs(w)), (kind, a["name"], k, v, w)


def test_eval_runs_the_lines_of_a_pairs_file(tmp_path):
    d = fountain()
    proc = run_fviz("eval", "--pairs", d / "pairs_with_gt.txt", "--images", d / "images", "--frames", "2:4",
                    "-e", "magsac", *FAST, "--out-dir", tmp_path / "run", "--workers", "1", "--no-progress", timeout=400)
    assert proc.returncode == 0, proc.stderr
    recs = [json.loads(l) for l in (tmp_path / "run" / "results.jsonl").read_text().splitlines()]
    assert [r["ref"]["frame_a"] for r in recs] == [2, 3] and all(r["error"] is None for r in recs)
    lines = (d / "pairs_with_gt.txt").read_text().splitlines()
    for r in recs:
        name0, name1 = lines[r["ref"]["frame_a"]].split()[:2]
        assert (r["ref"]["image_a"], r["ref"]["image_b"]) == (name0, name1)
        F_ref = closed_form_F(strecha_projection(name0), strecha_projection(name1))
        assert same_up_to_sign(r["result"]["F_gt"], F_ref, 1e-6)
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["pairs"] == 2 and summary["estimators"]["magsac"]["errors"] == 0


@pytest.mark.parametrize("line, fragment", [
    ("0000.jpg 0001.jpg 0 0 1 2 3", "7 fields"),
    ("0000.jpg 0001.jpg 0 x" + " 1" * 34, "rot0 rot1 must be integers"),
    ("0000.jpg 0001.jpg 5 0" + " 1" * 34, "EXIF rotations are 0-3"),
    ("0000.jpg 0001.jpg 0 0 " + " ".join(["0"] * 34), "K0"),
])
def test_bad_pairs_line_names_file_and_line(tmp_path, line, fragment):
    d = fountain()
    bad = tmp_path / "bad.txt"
    bad.write_text("# comment\n0000.jpg 0001.jpg\n" + line + "\n")
    proc = run_fviz("eval", "--pairs", bad, "--images", d / "images", "--out-dir", tmp_path / "r", "--no-progress")
    assert_one_line_error(proc, 2, f"{bad}:3", fragment)


@pytest.mark.parametrize("rot", [(1, 1), (3, 2)])
def test_exif_rotation_of_a_pairs_line_turns_image_cameras_and_F(tmp_path, rot):
    """rot0 rot1 turn the images as SuperGlue does (np.rot90): SIFT on the turned images still sits on the
    turned ground truth, and the pose errors (rotation-invariant) stay small."""
    d = fountain()
    fields = (d / "pairs_with_gt.txt").read_text().splitlines()[0].split()
    fields[2:4] = map(str, rot)
    (tmp_path / "rot.txt").write_text(" ".join(fields) + "\n")
    doc, proc = inspect_json("--pairs", tmp_path / "rot.txt", "--images", d / "images", *FAST, "-e", "magsac",
                             "--out", tmp_path / "r.rrd")
    size = lambda k: [2048, 3072] if k % 2 else [3072, 2048]  # noqa: E731
    assert doc["pair"]["size_a"] == size(rot[0]) and doc["pair"]["size_b"] == size(rot[1])
    rows = {e["name"]: e["metrics"] for e in doc["estimators"]}
    assert doc["n_eval"] > 100 and rows["gt"]["sed_median"] < 0.5, rows["gt"]
    assert rows["magsac"]["pose_err_deg"] < 2.0 and "turned by rot" in proc.stderr


def test_eval_triage_table_without_ground_truth(tmp_path):
    """A names-only pairs file: no GT metric anywhere, pose AUC and NSGD recall n/a (not 0), triage and table run."""
    import csv

    d = fountain()
    (tmp_path / "names.txt").write_text("# names only: no ground truth\n0004.jpg 0005.jpg\n0005.jpg 0006.jpg\n")
    run = tmp_path / "run"
    proc = run_fviz("eval", "--pairs", tmp_path / "names.txt", "--images", d / "images", "-e", "8point", "-e", "magsac",
                    *FAST, "--out-dir", run, "--workers", "1", "--no-progress", timeout=400)
    assert proc.returncode == 0, proc.stderr
    recs = [json.loads(l) for l in (run / "results.jsonl").read_text().splitlines()]
    assert all(r["error"] is None and r["result"]["F_gt"] is None for r in recs)
    with open(run / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert {r["estimator"] for r in rows} == {"8point", "magsac"} and {r["ground_truth"] for r in rows} == {"none"}
    assert not set(GT_METRICS) & set(rows[0]) and all(float(r["agreement_nsgd"]) >= 0 for r in rows)
    figures = json.loads((run / "summary.json").read_text())["estimators"]
    for f in figures.values():
        assert f["nsgd_recall"] is None and set(f["pose_auc"].values()) == {None} and f["sed_median"] > 0
    md = (run / "summary.md").read_text()
    assert "no ground truth" in md
    # how far the two estimators' F are apart over the run: the median of the pairs' agreement matrices' cell
    nsgd = []
    for r in recs:
        ag = r["result"]["agreement"]
        i, j = ag["names"].index("8point"), ag["names"].index("magsac")
        nsgd.append(ag["matrix"][i][j])
    agreement = json.loads((run / "summary.json").read_text())["agreement"]["8point - magsac"]
    assert agreement["pairs"] == 2 and agreement["median_nsgd"] == pytest.approx(float(np.median(nsgd)))
    assert agreement["agree"] == sum(v < 0.05 for v in nsgd)
    assert f"| 8point - magsac | 2 | {float(np.median(nsgd)):.4g} | {agreement['agree']} of 2 |" in md
    tab = text(run / "eval.rrd", L.RUN_SUMMARY)[0]  # eval.rrd's summary tab says it too
    assert "## Agreement between the estimators" in tab and f"| 8point - magsac | 2 | {float(np.median(nsgd)):.4g} |" in tab
    for cmd in (["triage", "--out-dir", run], ["table", run]):
        proc = run_fviz(*cmd, timeout=300)
        assert proc.returncode == 0, proc.stderr
    assert "| magsac | n/a | n/a | n/a | n/a |" in (run / "table.md").read_text()


def test_eval_two_images_with_a_given_F(tmp_path):
    d = fountain()
    F = closed_form_F(strecha_projection("0000.jpg"), strecha_projection("0001.jpg"))
    (tmp_path / "F.txt").write_text("\n".join(" ".join(repr(float(v)) for v in row) for row in F))
    run = tmp_path / "run"
    proc = run_fviz("eval", "--image-a", d / "images" / "0000.jpg", "--image-b", d / "images" / "0001.jpg", "--F-gt",
                    tmp_path / "F.txt", "-e", "magsac", *FAST, "--out-dir", run, "--workers", "1", "--no-progress", timeout=300)
    assert proc.returncode == 0, proc.stderr
    (rec,) = [json.loads(l) for l in (run / "results.jsonl").read_text().splitlines()]
    res = rec["result"]
    assert res["ground_truth"] == "F" and same_up_to_sign(res["F_gt"], F, 1e-12)
    magsac = next(e for e in res["estimators"] if e["name"] == "magsac")["metrics"]
    assert "nsgd" in magsac and "rot_err_deg" not in magsac and "epipole_err_deg" not in magsac  # an F: no pose, no K
    assert magsac["nsgd"] < 0.01 and json.loads((run / "summary.json").read_text())["estimators"]["magsac"]["nsgd_recall"] == 1


@pytest.mark.parametrize("args, fragment", [
    (["--T-ab", "1 0 0 1 0 1 0 0 0 0 1 0"], "needs the intrinsics"),
    (["--T-ab", "0 0 0 1 0 0 0 0 0 0 0 0"], "not a rotation"),
    (["--K", "1,2,3"], "--K '1,2,3': 3 numbers"),
    (["--K-a", "100,100,50,50"], "--K-b: missing"),
    (["--F-gt", "1 2 3"], "--F-gt '1 2 3': 3 numbers"),
])
def test_bad_ground_truth_flags_are_one_line(tmp_path, args, fragment):
    d = fountain() / "images"
    proc = run_fviz("inspect", "pair", "--image-a", d / "0000.jpg", "--image-b", d / "0001.jpg", *args, "--out", tmp_path / "x.rrd")
    assert_one_line_error(proc, 2, fragment)


def test_inspect_picks_a_line_by_its_names(tmp_path):
    d = fountain()
    lines = (d / "pairs_with_gt.txt").read_text().splitlines()
    name0, name1 = lines[3].split()[:2]
    doc, _ = inspect_json("--pairs", d / "pairs_with_gt.txt", "--images", d / "images", "--image-a", name0,
                          "--image-b", name1, "-e", "magsac", *FAST, "--out", tmp_path / "n.rrd")
    assert (doc["pair"]["image_a"], doc["pair"]["image_b"], doc["pair"]["frame_a"]) == (name0, name1, 3)
    F_ref = closed_form_F(strecha_projection(name0), strecha_projection(name1))
    assert same_up_to_sign(doc["F_gt"], F_ref, 1e-6)
    proc = run_fviz("inspect", "pair", "--pairs", d / "pairs_with_gt.txt", "--images", d / "images", "--image-a", "0000.jpg",
                    "--image-b", "0009.jpg", "--out", tmp_path / "x.rrd")
    assert_one_line_error(proc, 2, "no line '0000.jpg 0009.jpg'")
