"""KITTI folders as users have them, through the real command line: colour-only (the colour download),
and a gray/colour pair, end to end (inspect and eval in subprocesses, recordings read back)."""

import json

import cv2
import numpy as np
import pytest
from cli_util import read_csv, run_fviz
from rerun.chunk import RrdReader

from fviz.record import layout as L
from fviz.record import reader as R

pytestmark = pytest.mark.kitti

SMALL = ("--max-keypoints", "800", "--no-progress")


def test_eval_over_a_colour_only_sequence(kitti_root, tmp_path):
    out = tmp_path / "run"
    r = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "04", "--pair", "stereo", "--cams", "2,3",
                 "-e", "magsac", *SMALL, "--workers", "1", "--out-dir", out, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "10 pairs (0 already done, 10 evaluated now, 0 not evaluated (pair errors)" in r.stderr
    rows = read_csv(out / "metrics.csv")
    assert [(int(x["frame_a"]), x["estimator"]) for x in rows] == [(f, e) for f in range(10) for e in ("gt", "magsac")]
    assert all(x["cam_a"] == "2" and x["cam_b"] == "3" and not x["error"] and not x["pair_error"] for x in rows)
    assert max(float(x["sed_median"]) for x in rows if x["estimator"] == "gt") < 0.5  # stereo GT: < 0.5 px
    infos = [ch for ch in RrdReader(str(out / "eval.rrd")).stream().to_chunks()
             if ch.entity_path.lstrip("/") == L.PAIR_INFO.lstrip("/")]
    assert sum(ch.to_record_batch().num_rows for ch in infos) == 10


def test_frames_and_cameras_of_a_colour_only_sequence_in_errors(kitti_root, tmp_path):
    r = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "02", "--pair", "temporal", "--frames", "0:11",
                 "--out-dir", tmp_path / "run")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip() == "error: --frames 0:11: odometry 02 has frames 0..9 of cameras 2 (START:END, END exclusive)"
    r = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "02", "--pair", "stereo",
                 "--out", tmp_path / "x.rrd")
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert "--cams: missing image folder" in r.stderr and "02/image_0 (cameras with images here: 2)" in r.stderr
    assert not (tmp_path / "x.rrd").exists()


def test_mixed_gray_colour_pair_is_gray_with_a_note(kitti_root, tmp_path):
    out = tmp_path / "mixed.rrd"
    r = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--cams", "0,2", "--frame", "1",
                 "--out", out, "--json", *SMALL[:2])
    assert r.returncode == 0, r.stderr
    note = "cameras 0,2 mix gray and colour: image b (camera 2) converted to gray; use --cams 0,1 or 2,3 for a pair of one kind"
    assert f"note: {note}" in r.stderr.splitlines()
    doc = json.loads(r.stdout)
    assert doc["notes"] == [note]
    assert note in R.text(out, L.SUMMARY)[0]
    blob = np.asarray(R.column(out, L.image("b"), "EncodedImage:blob")[0][0], dtype=np.uint8)
    assert cv2.imdecode(blob, cv2.IMREAD_UNCHANGED).ndim == 2  # recorded as the estimators saw it
