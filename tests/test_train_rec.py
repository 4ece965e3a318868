"""The REC head's translation: kept near unit length during training (fviz/models/heads.py).

A model whose raw t grew long (the synthetic model's is ~(-0.3, 0, 16.7), straight ahead) cannot turn
its translation towards a stereo baseline in a short run: the direction moves by step / ||raw t||. With
the raw t rescaled to unit length (F unchanged) and the loss keeping it there, the same run learns the
known stereo motion."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from fviz.geometry import fundamental_from_motion, normalize
from fviz.models.model import FNet
from fviz.train.checkpoint import save_checkpoint
from fviz.train.data import TensorPairs
from fviz.train.loop import train, unit_translation
from fviz.train.recipe import Recipe

pytestmark = pytest.mark.usefixtures("torch_one_thread")

H, W = 32, 96
TINY = {"input_size": [H, W], "width": 8, "hidden": 16, "pool_grid": [2, 4], "dropout": 0.0}
K = np.array([[0.6 * W, 0, (W - 1) / 2], [0, 0.6 * W, (H - 1) / 2], [0, 0, 1]])
STEREO_T = np.array([-0.54, 0.0, 0.0])  # KITTI's left -> right baseline, metres


def stereo_pairs(n: int, seed: int) -> TensorPairs:
    """Random images, every F the rectified stereo F of the known motion (R = I, t = STEREO_T)."""
    F = normalize(fundamental_from_motion(K, K, np.eye(3), STEREO_T), "fbn")
    imgs = torch.from_numpy(np.random.default_rng(seed).random((2, n, 1, H, W)).astype(np.float32))
    return TensorPairs(imgs[0], imgs[1], torch.from_numpy(np.stack([F] * n)).float())


def forward_model(tmp_path) -> str:
    """A tiny model predicting straight-ahead motion with a long raw t, like the bundled synthetic one."""
    torch.manual_seed(0)
    model = FNet.from_variant("siamese-rec-pos-fbn", input_hw=(H, W), width=8, hidden=16, pool_grid=(2, 4), dropout=0.0)
    with torch.no_grad():
        last = model.head.fc[-1]
        last.weight[5:8] = 0
        last.bias[5:8] = torch.tensor([-0.3, 0.0, 16.7])
    return str(save_checkpoint(tmp_path / "forward.pt", model))


def recipe(tmp_path, init: str, t_norm_weight: float, steps: int = 60) -> Recipe:
    return Recipe.from_dict({
        "model": {"variant": "siamese-rec-pos-fbn", **TINY},
        "data": {"source": "synthetic", "train_size": 8, "val_size": 4, "val_points": 32},
        "train": {"batch_size": 8, "lr": 1e-3, "epochs": 1000, "max_steps": steps, "num_workers": 0, "seed": 0,
                  "out_dir": str(tmp_path / f"run{t_norm_weight}"), "init": init, "t_norm_weight": t_norm_weight,
                  "val_every": steps},
    })


def test_a_tiny_model_learns_a_known_stereo_motion_from_a_forward_start(tmp_path):
    init = forward_model(tmp_path)
    data = stereo_pairs(16, 0), stereo_pairs(8, 1)
    unit = train(recipe(tmp_path, init, 0.01), datasets=data, record=False, held_out=False)
    long = train(recipe(tmp_path, init, 0.0), datasets=data, record=False, held_out=False)
    # f_dist: distance of unit-norm F up to sign, 0 = the stereo F, ~1.4 = the forward F it started from
    assert unit.metrics["f_dist"] < 0.4, unit.metrics
    assert unit.metrics["f_dist"] < 0.5 * long.metrics["f_dist"], (unit.metrics, long.metrics)
    assert unit.metrics["sed_px"] < 1.0 and long.metrics["sed_px"] > unit.metrics["sed_px"]


def test_rescaling_the_translation_keeps_every_F(tmp_path):
    from fviz.train.checkpoint import load_model

    model, _ = load_model(forward_model(tmp_path))
    model.eval()
    data = stereo_pairs(8, 2)
    img_a, img_b, _ = data[list(range(8))]
    with torch.no_grad():
        before = model(img_a, img_b)
        factor = unit_translation(model, data, 8, torch.device("cpu"))
        after = model(img_a, img_b)
        raw = model.head.t_raw_norm
    assert factor == pytest.approx(1 / np.hypot(0.3, 16.7), rel=1e-5)
    torch.testing.assert_close(after, before, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(raw, torch.ones_like(raw), rtol=1e-5, atol=1e-6)
