"""Regression heads (Sec. 3.2): pooled features -> an (unnormalized) F in model-input pixels.

Every head is a two-layer MLP, FC(n_in -> hidden) -> ReLU -> Dropout -> FC(hidden -> k), followed by
a fixed, differentiable map from the k outputs to F (B, 3, 3) such that ``x_b^T F x_a = 0`` with x
in homogeneous pixel coordinates of the model input (H, W) (OpenCV origin: pixel centres at
integers).  The normalization layer comes after the head (:mod:`fviz.models.normalization`).

- :class:`BaseHead` (k = 9): the nine entries of F directly; no rank constraint.
- :class:`RecHead` (k = 8, the reconstruction layer): (f_a, f_b, rx, ry, rz, tx, ty, tz) ->
  F = K_b^-T [t]x R K_a^-1 with K_i = [[f_i, 0, cx], [0, f_i, cy], [0, 0, 1]], the principal point at
  the image centre (cx, cy) = ((W - 1) / 2, (H - 1) / 2), R = Rx(rx) Ry(ry) Rz(rz) (Euler angles, radians)
  and the motion X_b = R X_a + t, i.e. exactly :func:`fviz.geometry.fundamental_from_motion`.
  Output scaling (what the FC predicts): f_i = max(H, W) exp(2 tanh(raw_i / 2)) (positive, bounded),
  angles = 0.1 rad x raw (rotations between two views are small; this only sets the output unit),
  t = raw / ||raw|| (F is homogeneous in t).  The direction moves by (step of raw) / ||raw||: a raw t
  that grew long (the synthetic model's is ~(-0.3, 0, 16.7)) turns 16x slower than the angles, and a
  stereo target is then absorbed by a yaw bias.  Training therefore keeps ||raw|| near 1:
  :meth:`RecHead.unit_translation_` rescales the t outputs of a loaded model so that their median
  length is 1 (F unchanged), and the loss adds ``train.t_norm_weight * mean(log ||raw||)^2``
  (:attr:`RecHead.t_raw_norm`, the lengths of the last forward pass).
  Rank 2 by construction ([t]x has rank 2).
- :class:`EpiHead` (k = 8, the epipolar parametrization): two columns c1, c2 and (alpha, beta);
  the third column is alpha c1 + beta c2, so F (alpha, beta, -1)^T = 0: rank 2 by construction, and
  (alpha, beta) is the epipole in image a (in the conditioned coordinates below, when conditioned).  This cannot
  represent an epipole at infinity (rectified stereo), a limitation of the parametrization itself.

Conditioning (``conditioned=True``, the default; a deviation from the paper documented here): the
Base and EPI heads produce F_n in *conditioned* coordinates x_n = T x, T = [[1/s, 0, -cx/s],
[0, 1/s, -cy/s], [0, 0, 1]], s = max(H, W) / 2 (the image spans [-1, 1] along its long side), and
return F = T^T F_n T in pixels.  This is a fixed invertible linear map of the outputs (rank is kept)
that makes all nine raw outputs O(1) for real geometries, instead of entries that differ by
(W / 2)^2 in pixel coordinates, which eases the regression.  ``conditioned=False`` regresses the
pixel-coordinate entries directly, as the paper does.  REC needs no conditioning: its K does that.

Initialization: the last FC layer of every head starts with weights 100x smaller than PyTorch's
default, so that a fresh network predicts nearly the same F for every pair and training starts by
fitting the average geometry.  Measured on synthetic scenes: with the default initialization the
REC head at lr 1e-3 started from random rotations/translations and stayed at a validation loss of
0.31 (median epipolar distance 30 px at 48 x 160); with the small one it reached 0.005 (1.7 px) in
the same 300 steps.

All geometry runs in float32 even under autocast.
"""

from __future__ import annotations

import torch
from torch import nn

FOCAL_RANGE = 2.0  # REC: f = max(H, W) * exp(2 tanh(raw / 2)), within [0.14, 7.4] x max(H, W)
ANGLE_UNIT = 0.1  # REC: Euler angles = 0.1 rad x raw output
OUTPUT_INIT_SCALE = 0.01  # the last FC layer starts with weights 100x smaller than PyTorch's default


def mlp(n_in: int, hidden: int, n_out: int, dropout: float) -> nn.Sequential:
    """FC -> ReLU -> Dropout -> FC.  (B, n_in) -> (B, n_out)."""
    return nn.Sequential(nn.Linear(n_in, hidden), nn.ReLU(inplace=True), nn.Dropout(dropout), nn.Linear(hidden, n_out))


def skew(t: torch.Tensor) -> torch.Tensor:
    """Cross-product matrix.  (..., 3) -> (..., 3, 3)."""
    z = torch.zeros_like(t[..., 0])
    tx, ty, tz = t.unbind(-1)
    return torch.stack(
        [torch.stack([z, -tz, ty], -1), torch.stack([tz, z, -tx], -1), torch.stack([-ty, tx, z], -1)], -2
    )


def euler_to_rotation(angles: torch.Tensor) -> torch.Tensor:
    """R = Rx(rx) @ Ry(ry) @ Rz(rz), right-handed, radians.  (..., 3) -> (..., 3, 3)."""
    rx, ry, rz = angles.unbind(-1)
    one, zero = torch.ones_like(rx), torch.zeros_like(rx)
    cx, sx, cy, sy, cz, sz = rx.cos(), rx.sin(), ry.cos(), ry.sin(), rz.cos(), rz.sin()
    Rx = torch.stack([torch.stack([one, zero, zero], -1), torch.stack([zero, cx, -sx], -1), torch.stack([zero, sx, cx], -1)], -2)
    Ry = torch.stack([torch.stack([cy, zero, sy], -1), torch.stack([zero, one, zero], -1), torch.stack([-sy, zero, cy], -1)], -2)
    Rz = torch.stack([torch.stack([cz, -sz, zero], -1), torch.stack([sz, cz, zero], -1), torch.stack([zero, zero, one], -1)], -2)
    return Rx @ Ry @ Rz


def principal_point(input_hw: tuple[int, int]) -> tuple[float, float]:
    """Image centre (cx, cy) in pixel-centre coordinates of an (H, W) image."""
    return (input_hw[1] - 1) / 2.0, (input_hw[0] - 1) / 2.0


def inverse_intrinsics(f: torch.Tensor, cx: float, cy: float) -> torch.Tensor:
    """K^-1 for K = [[f, 0, cx], [0, f, cy], [0, 0, 1]].  (...,) -> (..., 3, 3)."""
    one, zero = torch.ones_like(f), torch.zeros_like(f)
    inv = 1.0 / f
    return torch.stack(
        [torch.stack([inv, zero, -cx * inv], -1), torch.stack([zero, inv, -cy * inv], -1), torch.stack([zero, zero, one], -1)],
        -2,
    )


def fundamental_from_params(
    f_a: torch.Tensor, f_b: torch.Tensor, angles: torch.Tensor, t: torch.Tensor, cx: float, cy: float
) -> torch.Tensor:
    """The reconstruction layer: F = K_b^-T [t]x R K_a^-1.  (B,), (B,), (B, 3), (B, 3) -> (B, 3, 3)."""
    Kb_inv_T = inverse_intrinsics(f_b, cx, cy).transpose(-1, -2)
    return Kb_inv_T @ skew(t) @ euler_to_rotation(angles) @ inverse_intrinsics(f_a, cx, cy)


def conditioning_matrix(input_hw: tuple[int, int], dtype=torch.float32, device=None) -> torch.Tensor:
    """T mapping pixels of an (H, W) image to coordinates spanning [-1, 1] along the long side.  (3, 3)."""
    cx, cy = principal_point(input_hw)
    s = max(input_hw) / 2.0
    return torch.tensor([[1 / s, 0.0, -cx / s], [0.0, 1 / s, -cy / s], [0.0, 0.0, 1.0]], dtype=dtype, device=device)


class _Head(nn.Module):
    n_out = 9

    def __init__(self, n_in: int, input_hw: tuple[int, int], hidden: int = 256, dropout: float = 0.5, conditioned: bool = True):
        super().__init__()
        self.input_hw = (int(input_hw[0]), int(input_hw[1]))
        self.conditioned = bool(conditioned)
        self.fc = mlp(n_in, hidden, self.n_out, dropout)
        with torch.no_grad():  # start close to a constant prediction (see the module docstring)
            self.fc[-1].weight.mul_(OUTPUT_INIT_SCALE)
        self.register_buffer("T", conditioning_matrix(self.input_hw), persistent=False)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """features (B, n_in) -> F (B, 3, 3), float32, pixel coordinates of the model input."""
        y = self.fc(features)
        with torch.autocast(device_type=y.device.type, enabled=False):
            return self.to_fundamental(y.float())

    def to_fundamental(self, y: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def _uncondition(self, F_n: torch.Tensor) -> torch.Tensor:
        if not self.conditioned:
            return F_n
        T = self.T.to(F_n.dtype)
        return T.transpose(0, 1) @ F_n @ T


class BaseHead(_Head):
    """FC -> the 9 entries of F (row-major).  (B, n_in) -> (B, 3, 3)."""

    n_out = 9

    def to_fundamental(self, y: torch.Tensor) -> torch.Tensor:
        return self._uncondition(y.reshape(-1, 3, 3))


class RecHead(_Head):
    """FC -> (f_a, f_b, rx, ry, rz, tx, ty, tz) -> K_b^-T [t]x R K_a^-1.  (B, n_in) -> (B, 3, 3), rank 2."""

    n_out = 8
    t_raw_norm: torch.Tensor | None = None  # (B,) ||raw t|| of the last forward pass (the loss keeps it near 1)

    def to_fundamental(self, y: torch.Tensor) -> torch.Tensor:
        scale = float(max(self.input_hw))
        f = scale * torch.exp(FOCAL_RANGE * torch.tanh(y[:, 0:2] / FOCAL_RANGE))
        angles = ANGLE_UNIT * y[:, 2:5]
        t = y[:, 5:8]
        norm = t.norm(dim=1, keepdim=True).clamp_min(1e-8)
        self.t_raw_norm = norm[:, 0]
        t = t / norm
        cx, cy = principal_point(self.input_hw)
        return fundamental_from_params(f[:, 0], f[:, 1], angles, t, cx, cy)


    @torch.no_grad()
    def unit_translation_(self, features: torch.Tensor) -> float:
        """Rescale the t outputs (last FC rows 5..7) so that the median ||raw t|| over ``features`` (B, n_in)
        is 1: every predicted F is unchanged, only how fast t turns during training.  Returns the factor."""
        was_training = self.training
        self.eval()
        raw = self.fc(features)[:, 5:8].float()
        self.train(was_training)
        factor = 1.0 / float(raw.norm(dim=1).median().clamp_min(1e-8))
        last = self.fc[-1]
        last.weight[5:8] *= factor
        last.bias[5:8] *= factor
        return factor


class EpiHead(_Head):
    """FC -> (c1, c2, alpha, beta) -> [c1, c2, alpha c1 + beta c2].  (B, n_in) -> (B, 3, 3), rank 2."""

    n_out = 8

    def to_fundamental(self, y: torch.Tensor) -> torch.Tensor:
        c1, c2 = y[:, 0:3], y[:, 3:6]
        alpha, beta = y[:, 6:7], y[:, 7:8]
        F_n = torch.stack([c1, c2, alpha * c1 + beta * c2], dim=-1)  # columns
        return self._uncondition(F_n)


HEADS = {"base": BaseHead, "rec": RecHead, "epi": EpiHead}


def make_head(head: str, n_in: int, input_hw: tuple[int, int], hidden: int, dropout: float, conditioned: bool) -> _Head:
    if head not in HEADS:
        raise ValueError(f"unknown head {head!r}")
    return HEADS[head](n_in, input_hw, hidden=hidden, dropout=dropout, conditioned=conditioned)
