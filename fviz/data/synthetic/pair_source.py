"""One synthetic pair with exact ground truth on the CPU (:func:`synthetic_pair`): the images of
:func:`fviz.data.synthetic.render_batch` plus exact correspondences, cast directly (rays x planes, the nearest
positive hit inside the rectangle) in float64 from random pixels of image a and kept where visible in b."""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
import torch

from fviz.data.pair import Pair, PairId
from fviz.data.synthetic.batch import generate, seed_list
from fviz.data.synthetic.config import SceneConfig, canonical
from fviz.data.synthetic.consts import scene_consts
from fviz.data.synthetic.raster import plane_coefficients
from fviz.data.synthetic.scene import sample_scenes

POINTS_SEED_SALT = 0xC0FF_EE11  # generator seed = seed ^ salt for the pixels sampled for correspondences
VISIBLE_RTOL = 1e-6  # relative depth tolerance of the visibility test in image b


def _cast(coef: np.ndarray, valid: np.ndarray, pix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit of the rays through pixels ``pix`` (M, 2) against all planes (P, 7, 3), float64.

    Returns 1/depth (M,) (0 where nothing is hit) and the plane index (M,) (-1 where nothing is hit).
    """
    vals = np.einsum("pkj,mj->mpk", coef, np.concatenate([pix, np.ones((len(pix), 1))], 1))  # (M, P, 7)
    inside = (vals[..., :4] >= 0).all(-1) & valid & (vals[..., 4] > 0)
    score = np.where(inside, vals[..., 4], -np.inf)
    best = score.max(-1)
    hit = np.isfinite(best)
    return np.where(hit, best, 0.0), np.where(hit, score.argmax(-1), -1)


def _view_planes(seed: int, cfg: SceneConfig) -> tuple[np.ndarray, np.ndarray]:
    """coef (2, P, 7, 3) and valid (2, P) of views a and b of one scene (numpy, for _cast)."""
    c = scene_consts(canonical(cfg), torch.device("cpu"))
    with torch.no_grad():
        sc = sample_scenes(torch.tensor([seed], dtype=torch.int64), cfg, c)
        coef, _, valid = plane_coefficients(sc["planes"], sc["R_cw"], sc["C"], c.kinv)
    return coef.numpy(), valid.numpy()


def _correspondences(
    seed: int, cfg: SceneConfig, coef: np.ndarray, valid: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray
) -> dict[str, np.ndarray]:
    """Exact correspondences: pixels of a, their 3D points, kept where visible in b.

    coef (2, P, 7, 3), valid (2, P): the planes of views a and b.  Returns points_a, points_b
    (M, 2) float64 and the occluded ones (inside b but hidden there).
    """
    W, H = cfg.width, cfg.height
    gen = torch.Generator().manual_seed(seed ^ POINTS_SEED_SALT)
    pix = (torch.rand(cfg.n_points, 2, generator=gen, dtype=torch.float64) * torch.tensor([W - 1.0, H - 1.0])).numpy()
    K_inv = np.linalg.inv(K)
    w_a, _ = _cast(coef[0], valid[0], pix)
    hit = w_a > 0
    X_a = (np.concatenate([pix[hit], np.ones((hit.sum(), 1))], 1) @ K_inv.T) / w_a[hit, None]
    X_b = X_a @ R.T + t
    x_b = X_b @ K.T
    in_front = x_b[:, 2] > 0
    x_b = x_b[:, :2] / np.where(in_front, x_b[:, 2], 1.0)[:, None]
    inside = in_front & (x_b[:, 0] >= -0.5) & (x_b[:, 0] < W - 0.5) & (x_b[:, 1] >= -0.5) & (x_b[:, 1] < H - 0.5)
    w_b, _ = _cast(coef[1], valid[1], x_b[inside])
    z_b = X_b[inside, 2]
    visible = np.abs(w_b * z_b - 1.0) <= VISIBLE_RTOL  # the ray of b hits this very point first
    pa, pb = pix[hit][inside], x_b[inside]
    return {
        "points_a": pa[visible],
        "points_b": pb[visible],
        "occluded_a": pa[~visible],
        "occluded_b": pb[~visible],
        "n_sampled": len(pix),
        "n_hit": int(hit.sum()),
        "n_inside_b": int(inside.sum()),
    }


def synthetic_pair(seed: int, config: SceneConfig | None = None) -> Pair:
    """One synthetic pair with exact ground truth, on the CPU.

    Images are uint8 (H, W); points_a/points_b the exact correspondences (M, 2) float64 of
    ``config.n_points`` random pixels of a that are visible in b.  ``extra`` holds depth_a,
    depth_b (H, W) float32 (inf for sky), the occluded samples (occluded_a, occluded_b: inside b
    but hidden there), the sample counts and the config.
    """
    cfg = canonical(config or SceneConfig())
    seed = seed_list([seed])[0]
    out = generate(torch.tensor([seed], dtype=torch.int64), cfg, scene_consts(cfg, torch.device("cpu")), True, internals=True)
    K, R, t = (out[k][0].numpy() for k in ("K_a", "R", "t"))
    corr = _correspondences(seed, cfg, out["coef"].numpy(), out["valid"].numpy(), K, R, t)
    to_u8 = lambda x: (x[0, 0] * 255.0).round().to(torch.uint8).numpy()
    pid = PairId(
        source="synthetic",
        sequence=str(seed),
        kind="stereo" if cfg.stereo else "temporal",
        frame_a=0,
        frame_b=1,
        cam_a=0,
        cam_b=1 if cfg.stereo else 0,
    )
    extra = {
        "depth_a": out["depth_a"][0, 0].numpy(),
        "depth_b": out["depth_b"][0, 0].numpy(),
        **{k: corr[k] for k in ("occluded_a", "occluded_b", "n_sampled", "n_hit", "n_inside_b")},
        "config": asdict(cfg),
    }
    return Pair(
        id=pid,
        image_a=to_u8(out["image_a"]),
        image_b=to_u8(out["image_b"]),
        K_a=K.copy(),
        K_b=K.copy(),
        R=R.copy(),
        t=t.copy(),
        F_gt=out["F"][0].numpy(),
        gt_accuracy_px=0.0,
        points_a=corr["points_a"],
        points_b=corr["points_b"],
        extra=extra,
    )
