"""3-vector and 3x3 maths as separate elementwise ops (no BLAS, sin and cos as polynomials): + - * / sqrt only, so
the scenes' parameters are bit-identical on any device and for any batch size."""

from __future__ import annotations

import torch


def dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    a0, a1, a2 = a.unbind(-1)
    b0, b1, b2 = b.unbind(-1)
    return torch.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], -1)


def mv(A: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """A (..., 3, 3) times x (..., 3), broadcasting, as separate elementwise ops (no BLAS)."""
    return A[..., 0] * x[..., 0:1] + A[..., 1] * x[..., 1:2] + A[..., 2] * x[..., 2:3]


def mm(A: torch.Tensor, B: torch.Tensor) -> torch.Tensor:
    """A (..., 3, 3) @ B (..., 3, 3), broadcasting, as separate elementwise ops (no BLAS)."""
    return A[..., :, 0:1] * B[..., 0:1, :] + A[..., :, 1:2] * B[..., 1:2, :] + A[..., :, 2:3] * B[..., 2:3, :]


def sincos(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """sin and cos of |x| <= 4 from + - * only (the same bits on every device and batch size).

    Taylor polynomials at x / 8 (error < 1e-18), then three angle doublings.
    """
    y = x * 0.125
    y2 = y * y
    s = y * (1.0 + y2 * (-1 / 6 + y2 * (1 / 120 + y2 * (-1 / 5040 + y2 * (1 / 362880 + y2 * (-1 / 39916800 + y2 / 6227020800))))))
    c = 1.0 + y2 * (-0.5 + y2 * (1 / 24 + y2 * (-1 / 720 + y2 * (1 / 40320 + y2 * (-1 / 3628800
                                                                       + y2 * (1 / 479001600 - y2 / 87178291200))))))
    for _ in range(3):
        s, c = 2.0 * s * c, (c - s) * (c + s)
    return s, c


def rotation(s: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Ry(yaw) @ Rx(pitch) @ Rz(roll) from sines and cosines (..., 3) of (yaw, pitch, roll).  -> (..., 3, 3).

    y points down, so a positive yaw turns right.
    """
    sy, sp, sr = s.unbind(-1)
    cy, cp, cr = c.unbind(-1)
    spsr, spcr = sp * sr, sp * cr
    rows = [cy * cr + sy * spsr, sy * spcr - cy * sr, sy * cp,
            cp * sr, cp * cr, -sp,
            cy * spsr - sy * cr, sy * sr + cy * spcr, cy * cp]  # fmt: skip
    return torch.stack(rows, -1).reshape(*s.shape[:-1], 3, 3)


def fundamental(R: torch.Tensor, t: torch.Tensor, K_inv: torch.Tensor) -> torch.Tensor:
    """F = K^-T [t]x R K^-1 with unit Frobenius norm, largest-|.| entry positive ('fbn').  (B, 3, 3)."""
    t0, t1, t2 = t.unbind(-1)
    zero = torch.zeros_like(t0)
    tx = torch.stack([zero, -t2, t1, t2, zero, -t0, -t1, t0, zero], -1).reshape(-1, 3, 3)
    F = mm(mm(K_inv.T, mm(tx, R)), K_inv)
    flat = F.reshape(-1, 9)
    sq = flat * flat
    sq = sq[:, 0:3] + sq[:, 3:6] + sq[:, 6:9]
    fro = (sq[:, 0] + sq[:, 1] + sq[:, 2]).sqrt()
    pivot = flat.gather(1, flat.abs().argmax(1, keepdim=True))
    return F * (pivot.sign() / fro[:, None])[..., None]
