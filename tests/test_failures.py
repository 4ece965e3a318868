"""Failures say why, where the user looks: eval and triage end with the run's failures grouped by cause,
with counts and one example each, and summary.md / summary.json hold the same groups. Real runs on KITTI frames."""

from __future__ import annotations

import json

import pytest
from cli_util import run_fviz

from fviz.failures import cause, failure_lines, failures_of

pytestmark = pytest.mark.kitti

FAST = ("--max-keypoints", "400", "--no-progress", "--workers", "1")

FLAKY = '''import cv2

def fn(pair, x_a, x_b):
    if pair.id.frame_a >= 1:
        raise ValueError(f"frame {pair.id.frame_a} is too hard for me")
    return cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)[0]
'''


def test_causes_leave_out_what_varies_between_pairs():
    assert cause("--gt-matches /data/gt: no BrusselsA_BrusselsB.txt") == cause("--gt-matches /data/gt: no x_y.txt")
    assert cause("ValueError: frame 3 is too hard") == cause("ValueError: frame 12 is too hard") == \
        "ValueError: frame … is too hard"
    assert cause("image b /tmp/x/7.png: no such file") == "image b …: no such file"
    assert cause("ahead needs K: give --K (or --K-a and --K-b)") == "ahead needs K: give --K (or --K-a and --K-b)"
    recs = [{"key": f"p{i}", "error": f"image b /x/{i}.png: no such file" if i else None,
             "result": {"estimators": [{"name": "ahead", "error": "needs K (give --K)"}]}} for i in range(3)]
    assert failure_lines(failures_of(recs)) == ["2 pairs not evaluated (error): image b /x/1.png: no such file (e.g. p1)",
                                                "ahead: error (no F) on 1/1 pairs: needs K (give --K) (e.g. p0)"]


def test_eval_and_triage_end_with_the_failures_grouped_by_cause(kitti_root, tmp_path):
    """A pairs file over KITTI frames without K, two of its three pairs naming images that are not there; `ahead`
    needs K: two causes, counted, one example each, at the end of eval's and triage's output and in the summaries."""
    images = tmp_path / "images"
    images.mkdir()
    for f in (0, 1):
        (images / f"{f}.png").symlink_to(kitti_root / "odometry/dataset/sequences/00/image_0" / f"{f:06d}.png")
    pairs = tmp_path / "pairs.txt"
    pairs.write_text("0.png 1.png\n0.png 7.png\n1.png 8.png\n")
    out = tmp_path / "run"
    r = run_fviz("eval", "--pairs", pairs, "--images", images, "-e", "ahead", "-e", "magsac", *FAST, "--out-dir", out,
                 timeout=300)
    assert r.returncode == 0, r.stderr
    expected = [f"2 pairs not evaluated (error): image b {images}/7.png: no such file (e.g. pairs/pairs/0.png--7.png)",
                "ahead: error (no F) on 1/1 pairs: ahead needs the cameras' intrinsics K, which this pair lacks: give --K (or "
                "--K-a and --K-b), or use a source with intrinsics (KITTI, a pairs file with K, a COLMAP model) "
                "(e.g. pairs/pairs/0.png--1.png)"]
    assert r.stderr.strip().splitlines()[-2:] == expected, r.stderr
    doc = json.loads((out / "summary.json").read_text())["failures"]
    assert [(g["cause"], g["count"]) for g in doc["pairs"]] == [("image b …: no such file", 2)]
    assert [(g["estimator"], g["count"], g["of"]) for g in doc["estimators"]] == [("ahead", 1, 1)]
    md = (out / "summary.md").read_text()
    assert "## Failures" in md and all(f"- {line}" in md for line in expected)
    from fviz.record import layout as L
    from fviz.record.reader import text

    tab = text(out / "eval.rrd", L.RUN_SUMMARY)[0]  # and eval.rrd's summary tab
    assert "## Failures" in tab and all(f"- {line}" in tab for line in expected)
    r = run_fviz("triage", "--out-dir", out, "--no-progress", "--by", "magsac", timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stderr.strip().splitlines()[-2:] == expected, r.stderr


def test_a_user_estimator_failing_on_some_pairs_is_one_cause(kitti_root, tmp_path):
    (tmp_path / "flaky.py").write_text(FLAKY)
    out = tmp_path / "run"
    r = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", "0:4",
                 "-e", "./flaky.py:fn", "-e", "ransac", *FAST, "--out-dir", out, cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last == ("fn: error (no F) on 2/3 pairs: ValueError: frame 1 is too hard for me "
                    "(e.g. odometry/00/temporal/f000001c0-f000002c0)"), r.stderr
    doc = json.loads((out / "summary.json").read_text())["failures"]
    assert doc["pairs"] == [] and [g["cause"] for g in doc["estimators"]] == ["ValueError: frame … is too hard for me"]
