"""Per-pair evidence for triage, computed by ``eval`` while the matches are at hand and stored in
results.jsonl (``diagnostics``): fviz.run imports this module, fviz.triage reads what it wrote.

Thresholds live here, beside the computations that use them; fviz.triage documents the tags.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fviz.evaluate import GT_NAME

HOMOGRAPHY_PX = 2.0
ROTATION_PX = 2.0
STATIC_PX = 0.5  # a match moving less than this is static (identical images: every match)
MIN_FIT = 8  # fewer inliers than this: no homography is fitted


def homography_fraction(x_a: np.ndarray, x_b: np.ndarray) -> float:
    """Fraction of the correspondences one RANSAC homography explains (NaN for fewer than MIN_FIT)."""
    import cv2

    if len(x_a) < MIN_FIT:
        return float("nan")
    cv2.setRNGSeed(0)
    H, mask = cv2.findHomography(x_a.astype(np.float64), x_b.astype(np.float64), cv2.RANSAC, HOMOGRAPHY_PX)
    return float("nan") if H is None else float(mask.ravel().astype(bool).mean())


def rotation_fraction(pair, x_a: np.ndarray, x_b: np.ndarray) -> float:
    """Fraction of matches the infinite homography K_b R K_a^-1 maps within ROTATION_PX."""
    if len(x_a) == 0:
        return float("nan")
    H = pair.K_b @ pair.R @ np.linalg.inv(pair.K_a)
    p = np.c_[x_a, np.ones(len(x_a))] @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.linalg.norm(p[:, :2] / p[:, 2:] - x_b, axis=1)
    return float(np.mean(np.nan_to_num(err, nan=np.inf) < ROTATION_PX))


def _estimator_evidence(r, m, gt_sed: np.ndarray, eval_threshold: float) -> dict[str, float]:
    inl = np.zeros(len(m), bool) if r.inliers is None else r.inliers
    n = int(inl.sum())
    known = n and gt_sed is not None
    return {
        "n_inliers": n,
        "homography_fraction": homography_fraction(m.x_a[inl], m.x_b[inl]),
        "gt_agree": float(np.mean(gt_sed[inl] < eval_threshold)) if known else float("nan"),
        "gt_sed_median_inliers": float(np.median(gt_sed[inl])) if known else float("nan"),
    }


def diagnose(pair, result) -> dict[str, Any]:
    """Evidence for the tags of one evaluated pair (JSON-ready; NaN where undefined), and the
    straight-ahead baseline's median SED on the evaluation matches (``ahead_sed_median``), so that
    triage can compare every run with it whether or not ``-e ahead`` was given."""
    from fviz.estimators.baselines import ahead
    from fviz.geometry import symmetric_epipolar_distance

    m = result.matches
    nan = float("nan")
    gt_sed = symmetric_epipolar_distance(pair.F_gt, m.x_a, m.x_b) if pair.has_gt else None  # the pair's GT, if any
    angle = np.degrees(np.arccos(np.clip((np.trace(pair.R) - 1) / 2, -1.0, 1.0))) if pair.R is not None else nan
    flow = np.linalg.norm(m.x_b - m.x_a, axis=1)
    xa, xb = m.x_a[result.eval_mask], m.x_b[result.eval_mask]
    ahead_sed = symmetric_epipolar_distance(ahead(pair, xa, xb), xa, xb) if pair.has_K else np.zeros(0)
    return {
        "n_matches": len(m),
        "baseline_m": float(np.linalg.norm(pair.t)) if pair.t is not None else nan,
        "rotation_deg": float(angle),
        "median_flow_px": float(np.median(flow)) if len(m) else float("nan"),
        "static_fraction": float(np.mean(flow < STATIC_PX)) if len(m) else float("nan"),
        "rotation_fraction": rotation_fraction(pair, m.x_a, m.x_b) if pair.has_pose else nan,
        "ahead_sed_median": float(np.median(ahead_sed)) if len(ahead_sed) else float("nan"),
        "estimators": {r.name: _estimator_evidence(r, m, gt_sed, result.eval_threshold_px)
                       for r in result.estimators if r.name != GT_NAME and not r.error},
    }
