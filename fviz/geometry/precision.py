"""RANSAC-free match precision: how many matches agree with the ground truth, before any estimator.

- ``epi_prec@1e-4`` / ``@5e-4`` / ``@1e-3``: glue-factory's ``epi_prec`` (``eval_matches_epipolar``): the
  share of matches whose symmetric epipolar distance to the true E = [t]x R, on points normalized by K^-1,
  is below the threshold; the distance is the mean of the two point-to-line distances (units of one focal
  length), line normals' squared lengths clamped at 1e-6 as there. t is taken as a unit vector (the distance
  does not depend on its scale but for that clamp);
- ``px_prec@1`` / ``@2`` / ``@4``: the share whose symmetric epipolar distance to F_gt is below 1 / 2 / 4 px.

On KITTI (f ~ 720 px) 1e-3 is ~0.7 px, 1e-4 ~0.07 px: below the ground truth's own accuracy on temporal pairs.
"""

from __future__ import annotations

import numpy as np

from fviz.geometry.epipolar import homogeneous
from fviz.geometry.fundamental import skew
from fviz.geometry.residuals import symmetric_epipolar_distance

EPI_THRESHOLDS = {"1e-4": 1e-4, "5e-4": 5e-4, "1e-3": 1e-3}  # glue-factory's names
PX_THRESHOLDS = {"1": 1.0, "2": 2.0, "4": 4.0}
PRECISION_KEYS = (*(f"epi_prec@{k}" for k in EPI_THRESHOLDS), *(f"px_prec@{k}" for k in PX_THRESHOLDS))
CLAMP = 1e-6  # glue-factory's floor on the squared line normals


def normalized_epipolar_distance(K_a, K_b, R, t, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """glue-factory's ``generalized_epi_dist(..., all=False, essential=True)``: (N, 2) pixels -> (N,)."""
    t = np.asarray(t, np.float64)
    E = skew(t / (np.linalg.norm(t) or 1.0)) @ np.asarray(R, np.float64)
    p_a = homogeneous(x_a) @ np.linalg.inv(K_a).T
    p_b = homogeneous(x_b) @ np.linalg.inv(K_b).T
    Ep_a, Etp_b = p_a @ E.T, p_b @ E
    r = np.abs(np.einsum("ni,ni->n", p_b, Ep_a))
    d_a = np.maximum(Ep_a[:, 0] ** 2 + Ep_a[:, 1] ** 2, CLAMP)
    d_b = np.maximum(Etp_b[:, 0] ** 2 + Etp_b[:, 1] ** 2, CLAMP)
    return r * (1 / np.sqrt(d_a) + 1 / np.sqrt(d_b)) / 2


def match_precision(K_a, K_b, R, t, F_gt, x_a: np.ndarray, x_b: np.ndarray) -> dict[str, float]:
    """The shares above (NaN for no match) of matches x_a, x_b (N, 2) under the true motion X_b = R X_a + t."""
    if len(x_a) == 0:
        return dict.fromkeys(PRECISION_KEYS, float("nan"))
    n = normalized_epipolar_distance(K_a, K_b, R, t, x_a, x_b)
    px = np.nan_to_num(symmetric_epipolar_distance(F_gt, x_a, x_b), nan=np.inf)
    return {**{f"epi_prec@{k}": float(np.mean(n < v)) for k, v in EPI_THRESHOLDS.items()},
            **{f"px_prec@{k}": float(np.mean(px < v)) for k, v in PX_THRESHOLDS.items()}}
