"""Per (config, device): the draw layout and every constant tensor the generator needs, made once and cached."""

from __future__ import annotations

import functools

import numpy as np
import torch

from fviz.data.synthetic.appearance import TEXTURE_SIZE, noise_bank, texture_bank
from fviz.data.synthetic.config import SceneConfig, intrinsics
from fviz.data.synthetic.draws import GOLDEN, PLACEMENT_TRIES, draw_layout, slot_kinds


class SceneConsts:
    """Per (config, device): the draw layout and every constant tensor the generator needs.

    Made outside any CUDA graph capture (the graph keeps references to these tensors).
    """

    def __init__(self, cfg: SceneConfig, device: torch.device) -> None:
        f64, i64 = torch.float64, torch.int64
        n, nb, H, W = cfg.facade_segments, cfg.n_boxes, cfg.height, cfg.width
        self.layout = L = draw_layout(cfg)
        lo, hi = np.array(L.lo), np.array(L.hi)
        as_t = functools.partial(torch.tensor, device=device)
        self.lo, self.span = as_t(lo, dtype=f64), as_t(hi - lo, dtype=f64)
        self.steps = (torch.arange(1, len(lo) + 1, dtype=i64) * GOLDEN).to(device)  # wraps like splitmix64
        kinds = slot_kinds(cfg)
        self.kscale = as_t([2.0 * cfg.texture_frequency / (TEXTURE_SIZE * m[0]) for m, _, _ in kinds], dtype=f64)
        self.e1 = as_t([e1 for _, e1, _ in kinds], dtype=f64).reshape(-1, 3)
        self.e2 = as_t([e2 for _, _, e2 in kinds], dtype=f64).reshape(-1, 3)
        self.side = as_t([[-1.0], [1.0]], dtype=f64)
        self.eye = torch.eye(3, dtype=f64, device=device)
        self.fixed_idx = torch.arange(4 * n, dtype=i64, device=device)
        self.box_x = torch.arange(2 * nb, dtype=i64, device=device) * 5 + 4 * n  # slot of face x0 of each box
        self.box_z, self.box_top = self.box_x + 2, self.box_x + 4
        self.tries = torch.arange(PLACEMENT_TRIES, dtype=i64, device=device)
        K = intrinsics(W, H)
        self.K = as_t(K, dtype=f64)
        self.K_inv = as_t(np.array([[1 / K[0, 0], 0, -K[0, 2] / K[0, 0]], [0, 1 / K[1, 1], -K[1, 2] / K[1, 1]], [0, 0, 1]]),
                          dtype=f64)
        self.kinv = (1 / K[0, 0], -K[0, 2] / K[0, 0], 1 / K[1, 1], -K[1, 2] / K[1, 1])
        self.rows = torch.arange(H, dtype=f64, device=device)[:, None, None]
        self.u = torch.arange(W, dtype=torch.float32, device=device)
        self.u_int = torch.arange(W, dtype=torch.int32, device=device)
        self.pix = torch.arange(H * W, dtype=torch.int32, device=device)
        self.bank = texture_bank(str(device))
        self.noise = noise_bank(str(device)) * (cfg.noise_sigma / 255.0) if cfg.noise_sigma > 0 else None  # grey levels


@functools.lru_cache(maxsize=8)
def scene_consts(cfg: SceneConfig, device: torch.device) -> SceneConsts:
    """The cached :class:`SceneConsts` of ``cfg`` (canonical: hashable) on ``device``."""
    return SceneConsts(cfg, device)
