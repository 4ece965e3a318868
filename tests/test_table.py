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
