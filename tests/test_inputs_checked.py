"""Inputs never silently changed or accepted: image arrays of any range, F given as an array or of rank 3, a result
logged over another pair, one K for images of two sizes, kusvod2's all-zero model file, COLMAP without 3D points,
--norm / --probe-by before the work, a transposed --T-ab, a .mat file, `fviz table X.rrd`, default recording names
with and without ground truth, non-finite ground truth, a cut JPEG, a cut images.bin, a threshold sweep's oracle without ground truth.

Every error is one line naming the argument or file (exit 2 on the command line); every change of a value a note."""

from __future__ import annotations

import os
import re
import struct

import cv2
import numpy as np
import pytest
import rerun as rr
from cli_util import assert_one_line_error, run_fviz

import fviz
from fviz.errors import FvizError

FAST = ("--max-keypoints", "400", "-e", "8point")


@pytest.fixture(scope="module")
def frames(kitti_root):
    seq = kitti_root / "odometry" / "dataset" / "sequences" / "00" / "image_0"
    return seq / "000000.png", seq / "000001.png"


@pytest.fixture(scope="module")
def kitti(kitti_root):
    return fviz.load_pair(kitti_root, sequence="00", frame=0, kind="temporal")


def one_line(exc) -> str:
    text = str(exc.value)
    assert "\n" not in text, text
    return text


# ------------------------------------------------------------------------------ image arrays: their range, said


def test_uint16_arrays_are_scaled_by_their_largest_value_with_a_note(kitti):
    a16 = kitti.image_a.astype(np.uint16) * 16  # 12-bit data in 16 bits (a raw camera's PNG read unchanged)
    pair = fviz.pair_from_images(a16, kitti.image_b)
    expected = np.round(a16 * (255.0 / a16.max())).astype(np.uint8)
    np.testing.assert_array_equal(pair.image_a, expected)  # not all white (it was: clipped at 255)
    assert 0 < pair.image_a.mean() < 250
    assert pair.notes == [f"image_a: uint16 values 0 .. {a16.max()}: scaled to 8 bits by that largest value"]


@pytest.mark.parametrize("scale, offset, note", [
    (1 / 255, 0.0, None),                      # floats in [0, 1]: times 255, as documented
    (1.0, 0.0, None),                          # floats of 8-bit levels (img.astype(float)): as they are
    (4.0, 0.0, "image_a: float64 values 0 .. {hi:g}: scaled to 8 bits by that largest value"),
    (1 / 255, -0.5, "image_a: float64 values {lo:g} .. {hi:g}: stretched to 0 .. 255 (8 bits)"),
])
def test_float_arrays_keep_their_range(kitti, scale, offset, note):
    img = kitti.image_a.astype(np.float64)
    given = img * scale + offset
    pair = fviz.pair_from_images(given, kitti.image_b)
    expected = np.round((img - img.min()) * (255.0 / np.ptp(img))) if offset else np.round(img * (255.0 / img.max())) \
        if scale > 1 else img
    np.testing.assert_allclose(pair.image_a, expected, atol=1)  # the picture, not a clipped white one
    assert pair.notes == ([] if note is None else [note.format(lo=given.min(), hi=given.max())])


def test_an_image_path_keeps_its_reading_notes(tmp_path, kitti):
    cv2.imwrite(str(tmp_path / "a.png"), kitti.image_a.astype(np.uint16) * 16)
    pair = fviz.pair_from_images(tmp_path / "a.png", kitti.image_b)
    assert any(n.startswith("image_a a.png has 16-bit samples") for n in pair.notes), pair.notes


@pytest.mark.parametrize("bad, fragment", [
    (np.full((40, 50), np.nan), "image_a: has NaN or infinite values"),
    (np.zeros((40, 50), bool), "image_a: expected uint8 or real numbers, got bool"),
    (np.zeros((40, 50), complex), "image_a: expected uint8 or real numbers, got complex128"),
])
def test_unusable_image_arrays_are_one_line(kitti, bad, fragment):
    with pytest.raises(FvizError) as exc:
        fviz.pair_from_images(bad, kitti.image_b)
    assert one_line(exc).startswith(fragment)


# ------------------------------------------------------------------------------ your F: a dict of numbers of rank 2


@pytest.fixture(scope="module")
def synthetic():
    return fviz.load_pair(synthetic=True, seed=0)


@pytest.mark.parametrize("F, fragment", [
    ("array", 'F: expected a dict of your matrices by name, {"mine": F}, got ndarray of shape (3, 3)'),
    ({"mine": np.array([["a"] * 3] * 3)}, "F['mine']: expected numbers"),
    ({"mine": [[1, 2, 3], [4, 5, "x"], [7, 8, 9]]}, "F['mine']: expected numbers"),
    ({"mine": np.eye(3)}, "F['mine']: rank 3 (singular values 1, 1, 1): an F has rank 2"),
])
def test_a_bad_own_F_is_one_line_naming_the_argument(synthetic, F, fragment):
    with pytest.raises(FvizError) as exc:
        fviz.inspect_pair(synthetic, (), F=synthetic.F_gt if F == "array" else F)
    assert one_line(exc).startswith(fragment)


def test_an_F_rounded_to_four_digits_is_still_an_F(kitti):
    F = kitti.F_gt / np.abs(kitti.F_gt).max()
    typed = np.array([float(f"{v:.4g}") for v in F.ravel()]).reshape(3, 3)  # rank 3 by rounding, a hair off
    s = np.linalg.svd(typed, compute_uv=False)
    assert s[2] > 1e-9 * s[1]
    result = fviz.inspect_pair(kitti, (), F={"typed": typed}, max_keypoints=400)
    assert result.get("typed").error is None


def test_a_rank_3_ground_truth_is_refused_from_python_and_the_command_line(frames, tmp_path, kitti):
    with pytest.raises(FvizError) as exc:
        fviz.pair_from_images(kitti.image_a, kitti.image_b, F_gt=np.diag([1.0, 2.0, 3.0]))
    assert one_line(exc).startswith("F_gt: rank 3 (singular values 1, 0.667, 0.333): an F has rank 2")
    r = run_fviz("inspect", "pair", "--image-a", frames[0], "--image-b", frames[1], "--F-gt", "1 0 0 0 2 0 0 0 3",
                 *FAST, "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, "--F-gt: rank 3 (singular values 1, 0.667, 0.333): an F has rank 2")
    assert not (tmp_path / "x.rrd").exists()


# ------------------------------------------------------------------------------ a result belongs to its pair


def test_a_result_is_logged_only_over_its_own_pair(synthetic, tmp_path):
    result = fviz.inspect_pair(synthetic, ("8point",), max_keypoints=400)
    other = fviz.load_pair(synthetic=True, seed=1)
    rec = rr.RecordingStream("inputs-checked")
    with pytest.raises(FvizError) as exc:
        fviz.log_result(rec, other, result)
    assert one_line(exc).startswith(f"result: computed on the pair {synthetic.id.name} (1242x375 and 1242x375), not "
                                    f"on this pair {other.id.name}")
    with pytest.raises(FvizError, match="^result: computed on the pair"):
        fviz.save_recording(tmp_path / "x.rrd", other, result)
    assert not (tmp_path / "x.rrd").exists()
    fviz.save_recording(tmp_path / "ok.rrd", synthetic, result)  # its own pair: written
    assert (tmp_path / "ok.rrd").stat().st_size > 0


def test_two_array_pairs_of_one_name_are_told_apart_by_their_pixels(kitti):
    a = fviz.pair_from_images(kitti.image_a, kitti.image_b)
    b = fviz.pair_from_images(kitti.image_b, kitti.image_a)  # same name (images/a--b), same sizes
    assert a.id.name == b.id.name and a.size_a == b.size_a
    result = fviz.inspect_pair(a, ("8point",), max_keypoints=400)
    with pytest.raises(FvizError) as exc:
        fviz.log_result(rr.RecordingStream("inputs-checked-2"), b, result)
    assert one_line(exc).startswith("result: computed on another pair named images/a--b (other pixels or ground truth)")


# ------------------------------------------------------------------------------ one K, one image size


def test_one_K_for_images_of_two_sizes_is_refused(kitti, frames, tmp_path):
    big = cv2.resize(kitti.image_b, None, fx=2, fy=2)
    with pytest.raises(FvizError) as exc:
        fviz.pair_from_images(kitti.image_a, big, K=kitti.K_a, R=kitti.R, t=kitti.t)
    assert one_line(exc).startswith("K: one K for both images, but image a is 1241x376 and image b 2482x752")
    K_b = np.diag([2.0, 2.0, 1.0]) @ kitti.K_b  # each its own K: a legitimate pair of resolutions
    pair = fviz.pair_from_images(kitti.image_a, big, K_a=kitti.K_a, K_b=K_b, R=kitti.R, t=kitti.t)
    assert pair.size_b == (2482, 752)
    cv2.imwrite(str(tmp_path / "big.png"), big)
    r = run_fviz("inspect", "pair", "--image-a", frames[0], "--image-b", tmp_path / "big.png",
                 "--K", "718.856,718.856,607.19,185.21", *FAST, "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, "--K: one K for both images, but image a is 1241x376 and image b 2482x752",
                          "give each image its own K (--K-a and --K-b)")


# ------------------------------------------------------------------------------ kusvod2's placeholder model


def test_an_all_zero_model_file_is_no_model_with_a_note(kitti, frames, tmp_path):
    from fviz.geometry import homogeneous, symmetric_epipolar_distance
    from fviz.geometry.fmbench import points_on_lines

    rng = np.random.default_rng(0)
    x_a = rng.random((200, 2)) * [1240, 375]
    x_b, ok = points_on_lines(homogeneous(x_a) @ kitti.F_gt.T, kitti.size_b, rng.random(200))
    x_a, x_b = x_a[ok][:40], x_b[ok][:40]
    ones = np.ones((len(x_a), 1))
    np.savetxt(tmp_path / "X_pts.txt", np.hstack([x_a, ones, x_b, ones, ones]))  # AdelaideRMF rows, all inliers
    np.savetxt(tmp_path / "X_model.txt", np.zeros((3, 3)))  # the published placeholder
    pair = fviz.load_pair(image_a=frames[0], image_b=frames[1], gt_matches=tmp_path / "X_pts.txt")
    assert np.median(symmetric_epipolar_distance(pair.F_gt, x_a, x_b)) < 1e-3  # fitted to the points
    assert any(n.startswith(f"{tmp_path / 'X_model.txt'} is all zeros (a placeholder, as kusvod2 ships for some pairs), "
                            "taken as no model: F_gt fitted to the 40 ground-truth correspondences") for n in pair.notes)
    np.savetxt(tmp_path / "X_model.txt", np.full((3, 3), np.nan))  # not a placeholder: still an error
    with pytest.raises(FvizError, match="X_model.txt:1: NaN or infinite numbers"):
        fviz.load_pair(image_a=frames[0], image_b=frames[1], gt_matches=tmp_path / "X_pts.txt")


# ------------------------------------------------------------------------------ flags: checked before the work, said


def test_a_colmap_model_without_3d_points_says_so_with_the_default_min_shared(strecha_root, capsys, monkeypatch):
    import fviz.errors
    from fviz.data.colmap import ColmapSource

    monkeypatch.setattr(fviz.errors, "_noted", set())  # said once per process: whatever this worker said before

    model = strecha_root / "fountain-P11" / "colmap"
    source = ColmapSource(model, strecha_root / "fountain-P11" / "images", None, 100)  # --min-shared 100 or none
    assert len(source.pair_ids()) == 55
    assert "--min-shared 100 does not apply" in capsys.readouterr().err


def test_norm_is_checked_before_the_images_are_read(tmp_path):
    r = run_fviz("inspect", "pair", "--image-a", tmp_path / "missing-a.png", "--image-b", tmp_path / "missing-b.png",
                 "--norm", "l2", "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, "--norm 'l2': choose one of etr, fbn, abs")  # not "no such file": the flag first
    with pytest.raises(FvizError, match="^norm 'l2': choose one of"):
        fviz.inspect_pair(fviz.load_pair(synthetic=True, seed=0), ("8point",), norm="l2")


MARKER_ESTIMATOR = '''
import os, cv2

def estimate(pair, x_a, x_b):
    open(os.environ["MARKER"], "w").write("ran")
    return cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)[0]
'''


def test_probe_by_is_checked_before_any_estimator_runs(tmp_path):
    (tmp_path / "marked.py").write_text(MARKER_ESTIMATOR)
    marker = tmp_path / "ran"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]),
               MARKER=str(marker))
    args = ("inspect", "pair", "--synthetic", "--max-keypoints", "400", "-e", "marked:estimate", "--out", tmp_path / "x.rrd")
    r = run_fviz(*args, "--probe-by", "magsac", env=env)
    assert_one_line_error(r, 2, "--probe-by magsac: not an estimator of this pair (estimate, gt; or score)")
    r2 = run_fviz(*args, "--probe-by", "score", env=env)
    assert_one_line_error(r2, 2, "--probe-by score: these matches have no scores")
    assert not marker.exists() and not (tmp_path / "x.rrd").exists()  # neither the estimator nor the writer ran
    r3 = run_fviz(*args, "--probe-by", "estimate", env=env)  # the same run with a valid one: it runs
    assert r3.returncode == 0, r3.stderr
    assert marker.exists()


@pytest.mark.parametrize("T, fragment", [
    ("1 0 0 0  0 1 0 0  0 0 1 0  0.5 0 0 1", "--T-ab: the last row of a 4x4 T is 0.5 0 0 1, not 0 0 0 1: the matrix is "
                                            "transposed (column-major); give it row by row"),
    ("1 0 0  0 1 0  0 0 1  0.5 0 0", "--T-ab: its 3x3 part is not a rotation (R R^T != I): its numbers are the 3x4 T "
                                    "column by column (transposed); give it row by row"),
])
def test_a_transposed_T_ab_is_named_as_such(frames, tmp_path, T, fragment):
    r = run_fviz("inspect", "pair", "--image-a", frames[0], "--image-b", frames[1], "--K", "718.856,718.856,607.19,185.21",
                 "--T-ab", T, *FAST, "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, fragment)
    assert "translation is zero" not in r.stderr


def test_a_mat_file_is_named_not_a_codec_error(frames, tmp_path):
    import scipy.io

    scipy.io.savemat(tmp_path / "gt.mat", {"data": np.random.default_rng(0).random((6, 20)), "label": np.ones(20)})
    for flag in ("--gt-matches", "--F-gt"):
        r = run_fviz("inspect", "pair", "--image-a", frames[0], "--image-b", frames[1], flag, tmp_path / "gt.mat",
                     *FAST, "--out", tmp_path / "x.rrd")
        assert_one_line_error(r, 2, f"{flag} {tmp_path / 'gt.mat'}: a MATLAB .mat file, not text: export its numbers as text")
        assert "codec" not in r.stderr
    (tmp_path / "pairs.txt").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(100))
    r = run_fviz("inspect", "pair", "--pairs", tmp_path / "pairs.txt", "--images", frames[0].parent, "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, f"--pairs {tmp_path / 'pairs.txt'}: an HDF5 file, not a text file of numbers")


def test_table_of_a_recording_says_it_is_not_a_run_folder(tmp_path):
    (tmp_path / "x.rrd").write_bytes(b"RRF2")
    for path in (tmp_path / "x.rrd", tmp_path / "missing.rrd"):
        r = run_fviz("table", path)
        assert_one_line_error(r, 2, f"{path}: a recording, not a run folder", f"fviz open {path}")
        assert "eval --out-dir" not in r.stderr


def test_default_recording_names_keep_runs_with_and_without_ground_truth(frames, kitti, tmp_path):
    from fviz.cli.inspect import default_out

    with_gt = ("--F-gt", ",".join(f"{v:.17g}" for v in kitti.F_gt.ravel()))
    r1 = run_fviz("inspect", "pair", "--image-a", frames[0], "--image-b", frames[1], *FAST, cwd=tmp_path)
    r2 = run_fviz("inspect", "pair", "--image-a", frames[0], "--image-b", frames[1], *FAST, *with_gt, cwd=tmp_path)
    assert r1.returncode == 0 and r2.returncode == 0, r1.stderr + r2.stderr
    written = sorted(p.name for p in (tmp_path / "runs").iterdir())
    assert len(written) == 2 and written[0].endswith(".F-gt.rrd") and written[1].endswith(".no-gt.rrd"), written
    assert f"recording: runs/{written[1]}" in r1.stdout and f"recording: runs/{written[0]}" in r2.stdout
    assert default_out("k/00", "pose") == default_out("k/00") != default_out("k/00", "none")


# ---------------------------------------------------- non-finite ground truth, cut files, a sweep without ground truth


@pytest.mark.parametrize("flag, value, fragment", [
    ("--F-gt", "nan 1 2 3 4 5 6 7 8", "--F-gt 'nan 1 2 3 4 5 6 7 8': 9 numbers, expected 9 finite ones"),
    ("--T-ab", "1 0 0 1e308 0 1 0 1e308 0 0 1 0", "--T-ab: its translation is not a finite number of metres"),
])
def test_non_finite_ground_truth_is_one_line(frames, tmp_path, flag, value, fragment):
    r = run_fviz("inspect", "pair", "--image-a", frames[0], "--image-b", frames[1], "--K", "718.856,718.856,607.19,185.21",
                 flag, value, *FAST, "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, fragment)


def test_non_finite_ground_truth_arrays_are_one_line(kitti):
    for kwargs, fragment in ((dict(F_gt=np.full((3, 3), np.inf)), "F_gt: has NaN or infinite entries"),
                             (dict(K=kitti.K_a, R=kitti.R, t=[np.nan, 0, 1]), "t: has NaN or infinite entries")):
        with pytest.raises(FvizError) as exc:
            fviz.pair_from_images(kitti.image_a, kitti.image_b, **kwargs)
        assert one_line(exc).startswith(fragment)


def test_a_cut_jpeg_is_refused_from_python_too(tmp_path, kitti):
    ok, buf = cv2.imencode(".jpg", kitti.image_a)
    (tmp_path / "cut.jpg").write_bytes(buf.tobytes()[: len(buf) // 2])
    with pytest.raises(FvizError) as exc:
        fviz.pair_from_images(tmp_path / "cut.jpg", kitti.image_b)
    assert one_line(exc).startswith(f"image_a {tmp_path / 'cut.jpg'}: the JPEG file is cut short (no end marker")


def test_a_cut_images_bin_is_one_line_on_the_command_line(strecha_root, tmp_path):
    import pycolmap

    d = tmp_path / "bin"
    d.mkdir()
    pycolmap.Reconstruction(str(strecha_root / "fountain-P11" / "colmap")).write_binary(str(d))
    whole = (d / "images.bin").read_bytes()
    (d / "images.bin").write_bytes(whole[: len(whole) - 100])
    r = run_fviz("inspect", "pair", "--colmap", d, "--images", strecha_root / "fountain-P11" / "images", "--index", "0",
                 "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, f"{d / 'images.bin'}: cut short or not a COLMAP binary file")
    assert struct.unpack("<Q", whole[:8])[0] == 11  # the model really had its 11 images


def names_only_pairs(frames, tmp_path):
    (tmp_path / "pairs.txt").write_text(f"{frames[0].name} {frames[1].name}\n")
    return ("--pairs", tmp_path / "pairs.txt", "--images", frames[0].parent, "--max-keypoints", "400")


def test_a_sweep_without_ground_truth_leaves_the_oracle_out_with_a_note(frames, tmp_path):
    src = names_only_pairs(frames, tmp_path)
    r = run_fviz("inspect", "pair", *src, "-e", "ransac", "--threshold", "0.5,2", "--json", "--out", tmp_path / "x.rrd")
    assert r.returncode == 0, r.stderr  # no estimator failed: the oracle was not run to fail
    import json

    names = [e["name"] for e in json.loads(r.stdout)["estimators"]]
    assert names == ["ransac-th0.5", "ransac-th2"]
    assert "note: ransac-th-oracle left out: a per-pair oracle keeps the threshold whose F is closest to the ground " \
           "truth, and this pair has none" in r.stderr
    r = run_fviz("eval", *src, "-e", "ransac", "--threshold", "0.5,2", "--out-dir", tmp_path / "run", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "note: ransac@oracle=0.5,2 left out: the per-pair oracle picks each pair's threshold by its ground truth" in r.stderr
    assert "oracle" not in (tmp_path / "run" / "metrics.csv").read_text()
    r = run_fviz("eval", *src, "-e", "ransac@oracle", "--out-dir", tmp_path / "run2", "--no-progress")
    assert_one_line_error(r, 2, "--estimator ransac@oracle: picks each pair's threshold by its ground truth, and no pair "
                                "of the selection has one")


def test_oracle_mean_without_ground_truth_is_one_line(frames, tmp_path):
    r = run_fviz("eval", *names_only_pairs(frames, tmp_path), "-e", "oracle-mean", "--out-dir", tmp_path / "r", "--no-progress")
    assert_one_line_error(r, 2, "--estimator oracle-mean: no pair of its selection has a ground-truth F")
    assert re.search(r"pairs/pairs/000000\.png--000001\.png has no ground truth", r.stderr)
