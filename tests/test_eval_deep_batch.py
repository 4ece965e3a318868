"""The deep estimator in batches inside ``fviz eval`` (what runs on a GPU when CUDA is present), on the CPU:
``FVIZ_DEEP_BATCH=cpu`` forces the batched path, ``off`` the per-pair one in the workers."""

import json
import os

import numpy as np
import pytest
from cli_util import run_fviz

from fviz.geometry import f_distance

pytestmark = [pytest.mark.kitti, pytest.mark.slow]


def eval_run(kitti_root, out, mode):
    env = dict(os.environ, FVIZ_DEEP_BATCH=mode)
    proc = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", "0:9",
                    "-e", "deep", "-e", "8point", "--features", "orb", "--max-keypoints", "400", "--workers", "2",
                    "--no-progress", "--out-dir", out, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return {r["key"]: {e["name"]: e for e in r["result"]["estimators"]} for r in map(json.loads, open(out / "results.jsonl"))}


def test_batched_deep_estimator_equals_the_per_pair_one(kitti_root, tmp_path):
    batched, per_pair = eval_run(kitti_root, tmp_path / "batched", "cpu"), eval_run(kitti_root, tmp_path / "per_pair", "off")
    assert sorted(batched) == sorted(per_pair) and len(batched) == 8
    for key, ests in batched.items():
        ref = per_pair[key]
        assert ests["deep"]["error"] is None
        # one forward pass over 8 pairs vs 8 passes of one: the same F up to float32 rounding
        assert f_distance(np.array(ests["deep"]["F"]), np.array(ref["deep"]["F"])) < 1e-4
        np.testing.assert_allclose(ests["deep"]["metrics"]["sed_median"], ref["deep"]["metrics"]["sed_median"], rtol=1e-3)
        assert ests["8point"]["metrics"] == ref["8point"]["metrics"]
    # every pair carries its share of the batch's time
    assert len({ests["deep"]["seconds"] for ests in batched.values()}) == 1


def test_predict_batch_equals_predict_one_by_one(odometry, torch_one_thread):
    from fviz.estimators.deep import bundled_weights
    from fviz.models.predict import predict_F, predict_F_batch
    from fviz.train.checkpoint import load_model

    model, _ = load_model(bundled_weights())
    pairs = [odometry.pair(f, "temporal") for f in (0, 5)] + [odometry.pair(0, "stereo")]
    images = [(p.image_a, p.image_b) for p in pairs]
    for F, (a, b) in zip(predict_F_batch(model, images), images):
        assert f_distance(F, predict_F(model, a, b)) < 1e-4
