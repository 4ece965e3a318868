"""The paper's normalization layers (Sec. 3.2) in torch: ETR, FBN, ABS.  (B, 3, 3) -> (B, 3, 3).

They agree with the numpy :func:`fviz.geometry.normalize` (tested):

- ``fbn``: divide by the Frobenius norm, sign fixed so that the largest-|.| entry is positive;
- ``abs``: divide by the largest-|.| entry, signed (that entry becomes +1);
- ``etr``: divide by F33.

ETR is undefined where F33 ~ 0 (rectified stereo pairs have F33 = 0 exactly; forward motion
nearly so).  What the layer does there depends on ``strict``:

- strict (the default in ``eval()`` mode, i.e. inference): raise
  :class:`fviz.geometry.NormalizationError` (an :class:`fviz.errors.FvizError`, one line, exit 2)
  when |F33| <= ``ETR_EPS`` * ||F||_F, the same test as the numpy side;
- not strict (the default in ``train()`` mode, and what the training loop's validation uses):
  divide by a sign-preserving clamp, sign(F33) * max(|F33|, ``ETR_TRAIN_EPS`` * ||F||_F) with
  sign(0) = +1, so that no entry exceeds 1 / ETR_TRAIN_EPS in magnitude and training never divides
  by zero.

FBN and ABS guard their denominators with a tiny absolute floor (an all-zero F stays zero).
All three compute in float32 (or float64 when given float64), also under autocast.

:func:`normalize_in_frame` normalizes F as it reads in another pixel frame (x' = U x per image) and maps it back: the
scale and sign are the other frame's. Rectified stereo has F33 = 0, so ETR is undefined in its own pixels; in the
unrectified cameras' pixels F33 carries most of ||F|| and ETR is defined (``FNetConfig.norm_frame``).
"""

from __future__ import annotations

import torch
from torch import nn

from fviz.geometry.fundamental import ETR_EPS, NORMS, NormalizationError

ETR_TRAIN_EPS = 1e-3  # relative clamp of |F33| in non-strict ETR
_TINY = 1e-12


def _signed_one(x: torch.Tensor) -> torch.Tensor:
    return torch.where(x >= 0, torch.ones_like(x), -torch.ones_like(x))


def _pivot(flat: torch.Tensor) -> torch.Tensor:
    """The entry of largest magnitude (first one on ties, as numpy's argmax).  (B, 9) -> (B,)."""
    return flat.gather(-1, flat.abs().argmax(-1, keepdim=True))[..., 0]


def normalize_f(F: torch.Tensor, norm: str, strict: bool = True) -> torch.Tensor:
    """Functional form of the layers.  (..., 3, 3) -> (..., 3, 3)."""
    if not F.dtype.is_floating_point or F.dtype in (torch.float16, torch.bfloat16):
        F = F.float()
    flat = F.reshape(*F.shape[:-2], 9)
    fro = flat.norm(dim=-1)
    if norm == "etr":
        f33 = F[..., 2, 2]
        if strict:
            if bool(torch.any(f33.abs() <= ETR_EPS * fro.clamp_min(1e-300))):
                raise NormalizationError(
                    "ETR normalization is undefined: the network's F has |F33| ~ 0 "
                    "(a model trained with ETR cannot represent this pair); use an fbn or abs model"
                )
            den = f33
        else:
            den = _signed_one(f33) * torch.maximum(f33.abs(), ETR_TRAIN_EPS * fro).clamp_min(_TINY)
        return F / den[..., None, None]
    if norm == "fbn":
        scale = _signed_one(_pivot(flat)) / fro.clamp_min(_TINY)
        return F * scale[..., None, None]
    if norm == "abs":
        p = _pivot(flat)
        den = _signed_one(p) * p.abs().clamp_min(_TINY)
        return F / den[..., None, None]
    raise ValueError(f"unknown norm {norm!r}: choose one of {', '.join(NORMS)}")


def normalize_in_frame(F: torch.Tensor, norm: str, frame: tuple[torch.Tensor, torch.Tensor] | None, strict: bool = True
                       ) -> torch.Tensor:
    """F normalized in the frame x' = U_a x_a, x' = U_b x_b and mapped back: U_b^T n(U_b^-T F U_a^-1) U_a, i.e. F
    times the scale (and sign) the norm gives it there.  ``frame`` = (U_a, U_b), (3, 3) each; None: F's own frame.
    (..., 3, 3) -> (..., 3, 3)."""
    if frame is None:
        return normalize_f(F, norm, strict)
    if not F.dtype.is_floating_point or F.dtype in (torch.float16, torch.bfloat16):
        F = F.float()
    U_a, U_b = (U.to(F.dtype) for U in frame)
    G = torch.linalg.inv(U_b).transpose(-1, -2) @ F @ torch.linalg.inv(U_a)
    return U_b.transpose(-1, -2) @ normalize_f(G, norm, strict) @ U_a


class FNorm(nn.Module):
    """Base of the three layers; ``strict=None`` means "strict in eval mode"."""

    name = ""

    def forward(self, F: torch.Tensor, strict: bool | None = None) -> torch.Tensor:
        strict = (not self.training) if strict is None else strict
        return normalize_f(F, self.name, strict)

    def extra_repr(self) -> str:
        return self.name


class ETR(FNorm):
    """Divide by F33 (see the module docstring for the F33 ~ 0 guard)."""

    name = "etr"


class FBN(FNorm):
    """Divide by the Frobenius norm; the largest-|.| entry made positive."""

    name = "fbn"


class ABS(FNorm):
    """Divide by the (signed) largest-|.| entry."""

    name = "abs"


def make_norm(name: str) -> FNorm:
    layers = {"etr": ETR, "fbn": FBN, "abs": ABS}
    if name not in layers:
        raise ValueError(f"unknown norm {name!r}: choose one of {', '.join(NORMS)}")
    return layers[name]()
