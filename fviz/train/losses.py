"""The training losses and the epipolar figures validation measures, in torch.

Loss (paper, Sec. 4): L1 + L2 between the predicted and the target F, both normalized by the
model's layer, per pair ``l1_weight * mean|F - F_t| + l2_weight * mean (F - F_t)^2``.  F is only
defined up to sign: for fbn and abs the loss of a pair is the smaller of the losses of F and -F
(in pixels ETR fixes the sign itself: F / F33 is the same for F and -F).  ``loss_frame = "conditioned"`` (the default) compares the matrices
after mapping both to coordinates where the image spans [-1, 1] along its long side
(:func:`fviz.models.heads.conditioning_matrix`) and normalizing them again; ``"pixel"`` compares
them in model-input pixels, the literal reading of the paper.  Measured on synthetic scenes (48 x 160,
Siamese REC+POS FBN, 1500 steps of batch 16, lr 1e-3): the pixel-frame loss never left its starting
plateau (validation loss 0.357, f_dist 1.03, the network collapsed to F ~ e3 e3^T), while the
conditioned one went below the constant straight-ahead F (median epipolar distance 1.34 px vs 1.50 px).
In pixels the entries of F differ by (W / 2)^2 and the last row and column dominate the loss.
(The authors' public code builds K^-1 without the principal point, in effect a centred frame too.)
ETR is re-normalized there by the Frobenius norm: in a centred frame F33 = c_b^T F c_a (the centres' residual), ~0
for stereo and forward motion, so dividing by it would weigh a pair by 1 / that residual.  There the loss takes the
better of +-F for ETR too: with the sign ETR gave it, the loss jumped where the network's F33 (in the ETR frame)
crosses 0, and 5 of 12 ETR networks of Table 1 stuck on the wrong side (median SED 2,200-394,000 px, see
docs/training.md); the minima are the same (F / F33 is).  So in this frame ETR and FBN train on one loss and differ
in the scale of their output.

:func:`sed_loss` (``train.sed_weight``) and validation (:mod:`fviz.train.validation`) measure F on points
drawn on the target's geometry (:func:`sample_points_on_geometry`).
"""

from __future__ import annotations

import torch


def _to_conditioned(F: torch.Tensor, input_hw: tuple[int, int], norm: str) -> torch.Tensor:
    from fviz.models.heads import conditioning_matrix
    from fviz.models.normalization import normalize_f

    T_inv = torch.linalg.inv(conditioning_matrix(input_hw, dtype=F.dtype, device=F.device))
    G = T_inv.transpose(0, 1) @ F @ T_inv
    if norm == "etr":  # keep ETR's sign, measure the direction
        return G / G.flatten(-2).norm(dim=-1).clamp_min(1e-12)[..., None, None]
    return normalize_f(G, norm, strict=False)


def f_loss(F_pred: torch.Tensor, F_t: torch.Tensor, norm: str, l1_weight: float = 1.0, l2_weight: float = 1.0,
           frame: str = "pixel", input_hw: tuple[int, int] | None = None) -> torch.Tensor:
    """L1 + L2 between normalized matrices, sign-invariant but for ETR in pixels.  (B, 3, 3) x 2 -> scalar."""
    F_pred, F_t = F_pred.float(), F_t.float()
    if frame == "conditioned":
        F_pred, F_t = _to_conditioned(F_pred, input_hw, norm), _to_conditioned(F_t, input_hw, norm)

    def per_pair(d: torch.Tensor) -> torch.Tensor:
        return l1_weight * d.abs().mean((-1, -2)) + l2_weight * d.square().mean((-1, -2))

    loss = per_pair(F_pred - F_t)
    if norm != "etr" or frame == "conditioned":
        loss = torch.minimum(loss, per_pair(F_pred + F_t))
    return loss.mean()


def sed_loss(F_pred: torch.Tensor, xa: torch.Tensor, xb: torch.Tensor, knee_px: float = 1.0) -> torch.Tensor:
    """Mean Charbonnier of the symmetric epipolar distance of ``F_pred`` on correspondences (x_b^T F_t x_a = 0):
    ~SED^2 / 2 below ``knee_px``, ~SED above it.  Scale- and sign-invariant in F.  (B, 3, 3), (B, n, 3) x 2 -> scalar."""
    sed = epipolar_metrics(F_pred, xa, xb)["sed"]
    return (knee_px * (torch.sqrt(1.0 + (sed / knee_px).square()) - 1.0)).mean().float()


def sample_points_on_geometry(F_t: torch.Tensor, input_hw: tuple[int, int], n: int, generator: torch.Generator
                              ) -> tuple[torch.Tensor, torch.Tensor]:
    """Points with x_b^T F_t x_a = 0: x_a uniform, x_b = a uniform point projected on F_t x_a.  -> (B, n, 3) x 2, float64."""
    B = F_t.shape[0]
    H, W = input_hw
    scale = torch.tensor([W - 1, H - 1], dtype=torch.float64)
    xa = torch.rand(B, n, 2, generator=generator, dtype=torch.float64) * scale
    p = torch.rand(B, n, 2, generator=generator, dtype=torch.float64) * scale
    one = torch.ones(B, n, 1, dtype=torch.float64)
    xa = torch.cat([xa, one], -1).to(F_t.device)
    p = torch.cat([p, one], -1).to(F_t.device)
    lines = xa @ F_t.double().transpose(-1, -2)  # (B, n, 3): l = F x_a
    ab2 = lines[..., :2].square().sum(-1, keepdim=True).clamp_min(1e-300)
    dist = (lines * p).sum(-1, keepdim=True)
    xb = p.clone()
    xb[..., :2] = p[..., :2] - dist * lines[..., :2] / ab2
    return xa, xb


def epipolar_metrics(F_pred: torch.Tensor, xa: torch.Tensor, xb: torch.Tensor) -> dict[str, torch.Tensor]:
    """Per-point |x_b^T F x_a| (unit-Frobenius F) and symmetric epipolar distance.  -> (B, n) each."""
    F = F_pred.double()
    F = F / F.flatten(1).norm(dim=1).clamp_min(1e-300)[:, None, None]
    Fxa = xa @ F.transpose(-1, -2)
    Ftxb = xb @ F
    r = (xb * Fxa).sum(-1)
    d_b = r.abs() / Fxa[..., :2].norm(dim=-1).clamp_min(1e-300)
    d_a = r.abs() / Ftxb[..., :2].norm(dim=-1).clamp_min(1e-300)
    return {"abs": r.abs(), "sed": 0.5 * (d_a + d_b)}


def f_distance_t(F_pred: torch.Tensor, F_t: torch.Tensor) -> torch.Tensor:
    a = F_pred.double().flatten(1)
    b = F_t.double().flatten(1)
    a = a / a.norm(dim=1, keepdim=True).clamp_min(1e-300)
    b = b / b.norm(dim=1, keepdim=True).clamp_min(1e-300)
    return torch.minimum((a - b).norm(dim=1), (a + b).norm(dim=1))
