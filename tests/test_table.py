"""``fviz table``: the paper's Table 1 layout from an eval run."""

import csv

import numpy as np
import pytest
from cli_util import assert_one_line_error, run_fviz


@pytest.fixture(scope="module")
def run_dir(kitti_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("table") / "run"
    proc = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", "0:3",
                    "-e", "8point", "-e", "lmeds", "-e", "ransac", "-e", "deep", "--workers", "1", "--no-progress",
                    "--out-dir", out, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return out


def test_table_layout_and_values(run_dir):
    proc = run_fviz("table", run_dir)
    assert proc.returncode == 0, proc.stderr
    with open(run_dir / "table.csv", newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], {r[0]: r[1:] for r in rows[1:]}
    assert header == ["Method", "ETR EPI-ABS", "ETR EPI-SQR", "FBN EPI-ABS", "FBN EPI-SQR", "ABS EPI-ABS", "ABS EPI-SQR"]
    assert [r[0] for r in rows[1:]] == ["8-point", "LMedS", "RANSAC", "Siamese REC + POS", "Ground-truth"]
    # the bundled network is trained with FBN: only its FBN cells are filled
    assert [bool(c) for c in body["Siamese REC + POS"]] == [False, False, True, True, False, False]
    with open(run_dir / "metrics.csv", newline="") as f:
        per_pair = [r for r in csv.DictReader(f) if r["estimator"] == "lmeds"]
    assert len(per_pair) >= 2
    for col, key in zip(range(6), ["epi_abs_etr", "epi_sqr_etr", "epi_abs_fbn", "epi_sqr_fbn", "epi_abs_abs", "epi_sqr_abs"]):
        assert float(body["LMedS"][col]) == pytest.approx(np.mean([float(r[key]) for r in per_pair]), rel=1e-3)
    md = (run_dir / "table.md").read_text()
    assert "| Method |" in md and "mean" in md


def test_table_needs_an_eval_run(tmp_path):
    assert_one_line_error(run_fviz("table", tmp_path), 2, "metrics.csv", "missing")


def test_an_odometry_run_says_why_its_table_has_the_rectified_frame_only(run_dir):
    proc = run_fviz("table", run_dir)
    assert proc.returncode == 0, proc.stderr
    assert "## Table 1 in the paper's frame" in proc.stdout
    assert "rectified frame only: the paper's frame needs the unrectified cameras" in proc.stdout
    assert "calib.txt holds only the rectified projections" in proc.stdout
    assert not (run_dir / "table_frames.csv").exists()


@pytest.fixture(scope="module")
def raw_run(kitti_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("table") / "raw"
    proc = run_fviz("eval", "--kitti-root", kitti_root, "--drive", "2011_09_26_drive_0002", "--pair", "stereo",
                    "--frames", "0:2", "--max-keypoints", "600", "-e", "8point", "-e", "ransac", "--workers", "1",
                    "--no-progress", "--out-dir", out, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return out


def test_a_raw_drive_run_gets_the_papers_frame_under_both_readings(raw_run):
    proc = run_fviz("table", raw_run)
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("| Norm |")]
    assert len(lines) == 1, proc.stdout  # the benchmark's columns (benchmarks/paper_table1.py)
    head = [c.strip() for c in lines[0].split("|")[1:-1]]
    assert head[2] == "paper ABS / SQR" and head[3].startswith("A: unrectified frame, paper's filter")
    assert head[4].startswith("B: rectified pixels, unrectified GT, paper's filter") and head[5].startswith("A, fviz's filter")
    assert head[-3:] == ["÷ GT, paper", "÷ GT, A", "÷ GT, B"]
    cells = {(r[0], r[1]): r[2:] for r in ([c.strip() for c in ln.split("|")[1:-1]] for ln in proc.stdout.splitlines())
             if len(r) == len(head) and r[0] in ("ETR", "FBN", "ABS")}
    for norm in ("ETR", "FBN", "ABS"):
        for method in ("8-point", "RANSAC", "Ground-truth"):  # every reading filled, ETR too (F33 != 0 there)
            assert all(cells[norm, method][i] for i in range(4)), (norm, method, cells[norm, method])
    assert cells["ETR", "Ground-truth"][4] == "undefined" and cells["FBN", "Ground-truth"][-2:] == ["1 / 1", "1 / 1"]
    assert cells["FBN", "RANSAC"][0] == "0.27 / 0.21"
    gt = [float(cells[n, "Ground-truth"][1].split(" / ")[0]) for n in ("ETR", "FBN", "ABS")]
    assert max(gt) / min(gt) < 1.1 and 0.01 < gt[0] < 0.2  # the paper's frame: the three norms nearly agree
    with open(raw_run / "table_frames.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert {r["reading"] for r in rows} == {"unrectified", "rectified-pixels", "unrectified-fviz", "rectified"}
    a_gt = next(r for r in rows if r["reading"] == "unrectified" and r["Method"] == "Ground-truth")
    assert float(a_gt["FBN EPI-ABS"]) == pytest.approx(float(cells["FBN", "Ground-truth"][1].split(" / ")[0]), rel=1e-2)
    assert "Evaluation matches a pair (mean): A: unrectified frame, paper's filter" in proc.stdout
