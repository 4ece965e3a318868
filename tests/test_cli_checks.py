"""Flags checked before any work, and messages that name the right cause (a step past the sequence, a model that
is an image, a symlink loop, a corrupt PNG, the metrics triage accepts).
Real ``fviz`` subprocesses."""

from __future__ import annotations

import json
import shutil

import pytest
from cli_util import assert_one_line_error, run_fviz



INSPECT = ("inspect", "pair", "--synthetic", "--seed", "0", "--max-keypoints", "300")


def test_confidence_one_is_accepted_as_the_flag_says(tmp_path):
    r = run_fviz(*INSPECT, "-e", "ransac", "--confidence", "1.0", "--json", "--out", tmp_path / "x.rrd")
    assert r.returncode == 0, r.stderr
    ransac = next(e for e in json.loads(r.stdout)["estimators"] if e["name"] == "ransac")
    assert ransac["error"] is None and ransac["metrics"]["sed_median"] < 2
    assert_one_line_error(run_fviz(*INSPECT, "--confidence", "1.5", "--out", tmp_path / "y.rrd"), 2, "(0, 1]")


@pytest.mark.parametrize("args, flag", [
    (("--max-keypoints", "10000000000"), "--max-keypoints 10000000000"),
    (("--max-keypoints", "0"), "--max-keypoints 0"),
    (("--max-iters", "0"), "--max-iters 0"),
    (("--web", "--port", "0"), "--port 0"),
    (("--web", "--web-port", "70000"), "--web-port 70000"),
])
def test_out_of_range_flags_are_refused_before_any_work(tmp_path, args, flag):
    assert_one_line_error(run_fviz(*INSPECT, *args, "--out", tmp_path / "x.rrd"), 2, flag)
    assert not (tmp_path / "x.rrd").exists()


def test_a_step_longer_than_the_sequence_names_step(kitti_root, tmp_path):
    r = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--step", "100",
                 "--out-dir", tmp_path / "run", "--no-progress")
    assert_one_line_error(r, 2, "--step 100")
    assert "--frames" not in r.stderr


def test_a_model_that_is_an_image_is_not_said_to_hold_python_objects(kitti_root, tmp_path):
    png = kitti_root / "odometry" / "dataset" / "sequences" / "00" / "image_0" / "000000.png"
    r = run_fviz(*INSPECT, "-e", f"deep:{png}", "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, str(png), "not a torch file")
    assert "Python objects" not in r.stderr


def sequence_copy(kitti_root, tmp_path, frames=3):
    """A copy of sequence 00's cameras 0 and 1 at frame 0..frames-1 (images linked)."""
    src = kitti_root / "odometry" / "dataset" / "sequences" / "00"
    seq = tmp_path / "kitti" / "odometry" / "dataset" / "sequences" / "00"
    for cam in (0, 1):
        (seq / f"image_{cam}").mkdir(parents=True)
        for f in range(frames):
            (seq / f"image_{cam}" / f"{f:06d}.png").symlink_to(src / "image_0" / f"{f:06d}.png")
    shutil.copy(src / "calib.txt", seq)
    return tmp_path / "kitti", seq


def test_a_symlink_loop_is_called_a_loop_not_missing(kitti_root, tmp_path):
    root, seq = sequence_copy(kitti_root, tmp_path)
    img = seq / "image_1" / "000000.png"
    img.unlink()
    img.symlink_to(img)
    r = run_fviz("inspect", "pair", "--kitti-root", root, "--sequence", "00", "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, str(img), "symlink loop")


def test_a_corrupt_png_is_fviz_s_one_line_without_libpng_s(kitti_root, tmp_path):
    root, seq = sequence_copy(kitti_root, tmp_path)
    img = seq / "image_1" / "000000.png"
    data = bytearray(img.read_bytes())
    data[20] ^= 0xFF  # the IHDR chunk's CRC no longer matches: libpng reports it on stderr itself
    img.unlink()
    img.write_bytes(bytes(data))
    r = run_fviz("inspect", "pair", "--kitti-root", root, "--sequence", "00", "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, "corrupt image", str(img))
    assert "libpng" not in r.stderr


def test_triage_lists_only_metrics_it_accepts(tmp_path):
    out = tmp_path / "run"
    r = run_fviz("eval", "--synthetic", "--seeds", "0:1", "-e", "8point", "--max-keypoints", "300", "--workers", "1",
                 "--no-progress", "--out-dir", out, timeout=300)
    assert r.returncode == 0, r.stderr
    bad = run_fviz("triage", "--out-dir", out, "--metric", "bogus", "--no-progress", "--workers", "1", timeout=300)
    assert_one_line_error(bad, 2, "--metric 'bogus'", "sed_median")
    listed = bad.stderr.split("choose one of", 1)[1]
    assert "f_dist" not in listed
    assert_one_line_error(run_fviz("triage", "--out-dir", out, "--metric", "f_dist", "--no-progress", "--workers", "1",
                                   timeout=300), 2, "--metric f_dist")
