"""Estimators that need the cameras' intrinsics (``poselib-E``, ``ahead``) on a pair without K (two plain
images): inspect refuses them with one line naming the estimator and how to give K (exit 2); eval records it
as that estimator's failure on the pair and goes on. COLMAP's and PoseLib's F are uncalibrated: they run."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_util import assert_one_line_error, run_fviz

pytestmark = pytest.mark.kitti


@pytest.fixture(scope="module")
def images(kitti_root):
    seq = kitti_root / "odometry" / "dataset" / "sequences" / "00"
    P0 = next(line for line in (seq / "calib.txt").read_text().splitlines() if line.startswith("P0:"))
    P = np.array(P0.split()[1:], float).reshape(3, 4)
    return seq / "image_0" / "000000.png", seq / "image_0" / "000001.png", f"{P[0, 0]},{P[1, 1]},{P[0, 2]},{P[1, 2]}"


@pytest.mark.parametrize("name", ["poselib-E", "ahead", "poselib-E@2"])
def test_inspect_refuses_an_estimator_needing_K_on_a_pair_without_it(images, name, tmp_path):
    a, b, _ = images
    r = run_fviz("inspect", "pair", "--image-a", a, "--image-b", b, "-e", "8point", "-e", name, "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, "needs the cameras' intrinsics K", "--K", "--K-a", name.replace("@", "-th"))
    assert not (tmp_path / "x.rrd").exists()


def test_with_K_poselib_E_runs_and_colmap_needs_none(images, tmp_path):
    a, b, K = images
    r = run_fviz("inspect", "pair", "--image-a", a, "--image-b", b, "--K", K, "-e", "poselib-E", "--out", tmp_path / "k.rrd", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["estimators"][0]["error"] is None
    r = run_fviz("inspect", "pair", "--image-a", a, "--image-b", b, "-e", "colmap", "--out", tmp_path / "c.rrd", "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)["estimators"][0]
    assert est["error"] is None and est["metrics"]["sed_median"] < 2


def test_eval_records_the_estimator_needing_K_as_its_failure_and_goes_on(images, tmp_path):
    a, b, _ = images
    out = tmp_path / "run"
    r = run_fviz("eval", "--image-a", a, "--image-b", b, "-e", "poselib-E", "-e", "colmap", "--out-dir", out,
                 "--no-progress", timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    rec = json.loads((out / "results.jsonl").read_text().splitlines()[-1])
    assert rec["error"] is None
    errors = {e["name"]: e["error"] for e in rec["result"]["estimators"]}
    assert errors["colmap"] is None
    assert errors["poselib-E"].startswith("poselib-E needs the cameras' intrinsics K") and "\n" not in errors["poselib-E"]
    summary = json.loads((out / "summary.json").read_text())["estimators"]
    assert summary["poselib-E"]["errors"] == 1 and summary["colmap"]["errors"] == 0


def test_a_pair_without_ground_truth_whose_every_estimator_fails_is_still_recorded(tmp_path):
    """No F at all (no ground truth, the only estimator raised): the probe has nothing to draw and says so, the failure is
    reported in one line and the recording is written, without a traceback."""
    import os
    import sys

    from fviz.record import layout as L
    from fviz.record.reader import text
    from sources_util import fountain

    (tmp_path / "crash_mod.py").write_text("def crash(pair, x_a, x_b):\n    raise RuntimeError('my estimator crashed')\n")
    images = fountain() / "images"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}
    out = tmp_path / "p.rrd"
    proc = run_fviz("inspect", "pair", "--image-a", images / "0000.jpg", "--image-b", images / "0001.jpg",
                    "-e", "crash_mod:crash", "--out", out, env=env, timeout=600)
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == 1 and "my estimator crashed" in proc.stdout + proc.stderr
    assert "my estimator crashed" in "\n".join(text(out, L.SUMMARY))
    (probe,) = text(out, L.PROBE_TEXT)  # no probe step (no line to draw): the probe tab says why
    assert probe.startswith("**No probe**: no estimator gave an F")
