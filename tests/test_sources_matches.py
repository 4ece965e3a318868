"""A user's matches (--matches: hloc h5, SuperGlue npz, plain text) and ground-truth correspondences
(--gt-matches, AdelaideRMF layout) on fountain-P11, checked against OpenCV on the same matches and the
closed-form F of the published cameras."""

import json
import re

import cv2
import numpy as np
import pytest
from cli_util import assert_one_line_error, run_fviz
from fviz.geometry import sampson_distance
from fviz.record import layout as L
from fviz.record.reader import column, text
from sources_util import closed_form_F, fountain, mean_line_distance, same_up_to_sign, strecha_projection


@pytest.fixture(scope="module")
def sift_matches():
    """OpenCV SIFT (600 per image) + ratio test on fountain 0000 -> 0001, done by the test itself:
    keypoints (N, 2) x2, matches0 (N0,) with -1, scores (N0,)."""
    d = fountain() / "images"
    sift = cv2.SIFT_create(nfeatures=600)
    out = [sift.detectAndCompute(cv2.imread(str(d / n), cv2.IMREAD_GRAYSCALE), None) for n in ("0000.jpg", "0001.jpg")]
    kp = [np.array([k.pt for k in o[0]], float) for o in out]
    m0, scores = -np.ones(len(kp[0]), int), np.zeros(len(kp[0]))
    for a, b in cv2.BFMatcher().knnMatch(out[0][1], out[1][1], k=2):
        if a.distance < 0.8 * b.distance:
            m0[a.queryIdx], scores[a.queryIdx] = a.trainIdx, 1.0 - a.distance / 512.0
    return kp, m0, scores


def _points(sift_matches):
    kp, m0, scores = sift_matches
    i = np.flatnonzero(m0 >= 0)
    return kp[0][i], kp[1][m0[i]], scores[i]


def inspect_json(*args):
    proc = run_fviz("inspect", "pair", *args, "--json", timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout), proc


def _F(doc, name):
    return np.array(next(e["F"] for e in doc["estimators"] if e["name"] == name))


def _write_hloc(folder, kp, m0, scores, names=("0000.jpg", "0001.jpg"), key=None, dtype=np.float32):
    import h5py

    folder.mkdir(exist_ok=True)
    with h5py.File(folder / "features.h5", "w") as f:
        for n, k in zip(names, kp):
            f.create_group(n).create_dataset("keypoints", data=k.astype(dtype))
    with h5py.File(folder / "matches.h5", "w") as f:
        g = f.create_group(key or "/".join(n.replace("/", "-") for n in names))  # hloc's names_to_pair
        g["matches0"], g["matching_scores0"] = m0, scores.astype(np.float32)
    return folder / "matches.h5"


def test_hloc_matches_give_opencvs_F_and_the_ground_truth_of_the_pairs_file(sift_matches, tmp_path):
    kp, m0, scores = sift_matches
    h5 = _write_hloc(tmp_path / "hloc", kp, m0, scores)
    d = fountain()
    out = tmp_path / "m.rrd"
    doc, proc = inspect_json("--pairs", d / "pairs_with_gt.txt", "--images", d / "images", "--index", "0",
                             "--matches", h5, "-e", "8point", "-e", "magsac", "--probe-by", "score", "--out", out)
    x_a, x_b, s = _points(sift_matches)
    assert doc["n_matches"] == len(x_a) and "fviz's features not used" in proc.stderr
    # the matcher's scores: on hover of every match, and the probe walks the least confident first
    labels = column(out, L.matches("gt"), "Points2D:labels")[0]
    shown = sorted(float(t.rsplit(" ", 1)[1]) for t in labels[: len(x_a)])
    assert np.allclose(shown, np.sort(s.astype(np.float32)), atol=1e-3)
    steps = [float(re.search(r"score ([0-9.e-]+)", t).group(1)) for t in text(out, L.PROBE_TEXT)]
    F_gt = closed_form_F(strecha_projection("0000.jpg"), strecha_projection("0001.jpg"))
    near = mean_line_distance(F_gt, x_a.astype(np.float32).astype(float), x_b.astype(np.float32).astype(float)) < 2.0
    assert len(steps) == 20 and steps == sorted(steps) and steps[0] == pytest.approx(s[near].min(), abs=1e-3)
    # hloc's keypoints have OpenCV's origin: no shift, so the 8-point F is OpenCV's on the same points
    F_cv, _ = cv2.findFundamentalMat(x_a.astype(np.float32).astype(np.float64), x_b.astype(np.float32).astype(np.float64), cv2.FM_8POINT)
    assert same_up_to_sign(_F(doc, "8point") / np.linalg.norm(_F(doc, "8point")), F_cv / np.linalg.norm(F_cv), 1e-6)
    # the evaluation matches: those within 2 px (SED) of the published cameras' F, computed here
    F_gt = closed_form_F(strecha_projection("0000.jpg"), strecha_projection("0001.jpg"))
    xa32, xb32 = x_a.astype(np.float32).astype(float), x_b.astype(np.float32).astype(float)
    assert doc["n_eval"] == int(np.sum(mean_line_distance(F_gt, xa32, xb32) < 2.0)) > 100


def test_reversed_hloc_pair_superglue_npz_and_text_are_the_same_matches(sift_matches, tmp_path):
    from fviz.data.match_files import open_matches
    from fviz.data.images import two_images

    kp, m0, scores = sift_matches
    m0 = m0.copy()
    b, first = np.unique(m0, return_index=True)
    m0[np.setdiff1d(np.arange(len(m0)), first)] = -1  # one match per keypoint of b: the reversed vector holds them all
    x_a, x_b, s = _points((kp, m0, scores))
    d = fountain() / "images"
    pair = two_images(str(d / "0000.jpg"), str(d / "0001.jpg"))
    # hloc stored the pair the other way round (image 1 first): the reader swaps it back
    back = -np.ones(len(kp[1]), int)
    back[m0[m0 >= 0]] = np.flatnonzero(m0 >= 0)
    rev = _write_hloc(tmp_path / "rev", kp[::-1], back, np.zeros(len(kp[1])), names=("0001.jpg", "0000.jpg"), dtype=np.float64)
    np.savez(tmp_path / "0000_0001_matches.npz", keypoints0=kp[0], keypoints1=kp[1], matches=m0, match_confidence=scores)
    np.savetxt(tmp_path / "m.txt", np.c_[x_a, x_b, s], header="x_a y_a x_b y_b score")
    key = lambda c: sorted(map(tuple, np.c_[c.x_a, c.x_b]))  # noqa: E731
    want = sorted(map(tuple, np.c_[x_a, x_b]))
    for path in (rev, tmp_path / "0000_0001_matches.npz", tmp_path, tmp_path / "m.txt"):
        c = open_matches(path).for_pair(pair)
        assert key(c) == want, path
    c = open_matches(tmp_path / "m.txt").for_pair(pair)
    assert np.allclose(c.scores, s)


def test_plain_text_matches_without_ground_truth(sift_matches, tmp_path):
    x_a, x_b, s = _points(sift_matches)
    np.savetxt(tmp_path / "m.txt", np.c_[x_a, x_b, s])
    d = fountain() / "images"
    doc, _ = inspect_json("--image-a", d / "0000.jpg", "--image-b", d / "0001.jpg", "--matches", tmp_path / "m.txt",
                          "-e", "8point", "-e", "ransac", "--out", tmp_path / "t.rrd")
    assert doc["ground_truth"] == "none" and doc["n_matches"] == len(x_a)
    F_cv, _ = cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)
    assert same_up_to_sign(_F(doc, "8point") / np.linalg.norm(_F(doc, "8point")), F_cv / np.linalg.norm(F_cv), 1e-6)


def test_adelaide_gt_matches_fit_F_gt_and_are_the_evaluation_points(sift_matches, tmp_path):
    """AdelaideRMF rows x1 y1 1 x2 y2 1 label: inliers (label 1) are the matches within 1 px of the published
    cameras' F, outliers (label 0) the rest; F_gt is OpenCV's 8-point on the inliers."""
    x_a, x_b, _ = _points(sift_matches)
    F_pub = closed_form_F(strecha_projection("0000.jpg"), strecha_projection("0001.jpg"))
    label = (mean_line_distance(F_pub, x_a, x_b) < 1.0).astype(int)
    np.savetxt(tmp_path / "gt.txt", np.c_[x_a, np.ones(len(x_a)), x_b, np.ones(len(x_a)), label], fmt="%.6f")
    rows = np.loadtxt(tmp_path / "gt.txt")
    inl = rows[:, 6] != 0
    F_cv, _ = cv2.findFundamentalMat(rows[inl][:, [0, 1]], rows[inl][:, [3, 4]], cv2.FM_8POINT)
    d = fountain() / "images"
    doc, proc = inspect_json("--image-a", d / "0000.jpg", "--image-b", d / "0001.jpg", "--gt-matches", tmp_path / "gt.txt",
                             "--max-keypoints", "600", "--out", tmp_path / "g.rrd")
    assert doc["ground_truth"] == "correspondences" and doc["eval_points"] == "gt-matches"
    assert doc["n_eval"] == int(inl.sum()) > 100
    sampson = lambda F: np.median(sampson_distance(np.array(F), rows[inl][:, [0, 1]], rows[inl][:, [3, 4]]))  # noqa: E731
    assert sampson(doc["F_gt"]) <= 1.05 * sampson(F_cv)  # a robust fit: the median within 5 % of least squares
    gt = next(e for e in doc["estimators"] if e["name"] == "gt")["metrics"]
    assert "rot_err_deg" not in gt and "nsgd" in gt  # an F, no pose
    assert gt["sed_median"] < 1.0 and "F_gt fitted to the" in proc.stderr and "refined on their Sampson distance" in proc.stderr
    # the fitted F is close to the published one over the whole image: FM-Bench's NSGD well below its 0.05
    from fviz.geometry import nsgd

    d_fit, d_8pt = (nsgd(np.asarray(F), F_pub, (3072, 2048), (3072, 2048)) for F in (doc["F_gt"], F_cv))
    assert d_fit < 5e-3 and d_fit <= 1.1 * d_8pt, (d_fit, d_8pt)


@pytest.mark.parametrize("content, fragment", [
    ("10 20 30 40\n10 20 30\n", ":2: 3 columns"),
    ("10 20 30 40\n1 2 x 4\n", ":2: not numbers"),
    ("10 20 30 40\n10 20 5000 40\n", ":2: point (5000.0, 40.0) lies outside the 3072x2048 image b"),
])
def test_bad_matches_file_names_file_and_line(tmp_path, content, fragment):
    (tmp_path / "m.txt").write_text(content)
    d = fountain() / "images"
    proc = run_fviz("inspect", "pair", "--image-a", d / "0000.jpg", "--image-b", d / "0001.jpg", "--matches",
                    tmp_path / "m.txt", "--out", tmp_path / "x.rrd")
    assert_one_line_error(proc, 2, f"{tmp_path / 'm.txt'}{fragment}")


def test_hloc_file_without_the_pair_is_one_line(sift_matches, tmp_path):
    kp, m0, scores = sift_matches
    h5 = _write_hloc(tmp_path / "h", kp, m0, scores, names=("0000.jpg", "0002.jpg"))
    d = fountain() / "images"
    proc = run_fviz("inspect", "pair", "--image-a", d / "0000.jpg", "--image-b", d / "0001.jpg", "--matches", h5,
                    "--out", tmp_path / "x.rrd")
    assert_one_line_error(proc, 2, str(h5), "no pair 0000.jpg/0001.jpg")


def test_eval_with_hloc_matches_and_a_kitti_pair(kitti_root, tmp_path):
    """--matches works for KITTI too: hloc names are the images' paths under the sequence (image_0/000003.png)."""
    seq = kitti_root / "odometry" / "dataset" / "sequences" / "00"
    sift = cv2.SIFT_create(nfeatures=500)
    names = ("image_0/000003.png", "image_0/000004.png")
    out = [sift.detectAndCompute(cv2.imread(str(seq / n), cv2.IMREAD_GRAYSCALE), None) for n in names]
    kp = [np.array([k.pt for k in o[0]], float) for o in out]
    m0 = -np.ones(len(kp[0]), int)
    for m in cv2.BFMatcher(crossCheck=True).match(out[0][1], out[1][1]):
        m0[m.queryIdx] = m.trainIdx
    h5 = _write_hloc(tmp_path / "h", kp, m0, np.ones(len(kp[0])), names=names)
    proc = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", "3:5",
                    "--matches", h5, "-e", "8point", "--out-dir", tmp_path / "run", "--workers", "1", "--no-progress", timeout=300)
    assert proc.returncode == 0, proc.stderr
    (rec,) = [json.loads(l) for l in (tmp_path / "run" / "results.jsonl").read_text().splitlines()]
    assert rec["error"] is None and rec["result"]["n_matches"] == int((m0 >= 0).sum())
    i = np.flatnonzero(m0 >= 0)
    F_cv, _ = cv2.findFundamentalMat(kp[0][i].astype(np.float32).astype(float), kp[1][m0[i]].astype(np.float32).astype(float),
                                     cv2.FM_8POINT)
    F = np.array(next(e["F"] for e in rec["result"]["estimators"] if e["name"] == "8point"))
    assert same_up_to_sign(F / np.linalg.norm(F), F_cv / np.linalg.norm(F_cv), 1e-6)
