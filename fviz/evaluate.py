"""The paper's protocol (Sec. 4.1) for one pair -> one plain result object.

Evaluation correspondences are the matched keypoints whose symmetric epipolar distance to the
*ground-truth* F is below ``eval_threshold_px`` (2 px in the paper). On them, per estimator:

- ``epi_abs`` = mean |x_b^T F x_a|, ``epi_sqr`` = mean (x_b^T F x_a)^2 -- *means* per pair (the paper's
  text writes sums; its code and table use means), on F normalized by ``norm`` (FBN by default).
  Both are also given for every norm as ``epi_abs_<norm>`` / ``epi_sqr_<norm>`` (NaN for ETR when F33 ~ 0).
- ``sed_mean`` / ``sed_median``: symmetric epipolar distance (px); ``sampson_mean`` / ``sampson_median`` (px);
- ``n_inliers`` / ``inlier_ratio`` over all matches; ``epipole_err_deg``: the larger, over both images, of
  the angles between the viewing rays K^-1 e through the estimated and the true epipole;
- relative pose (SuperGlue / LightGlue): (R, t) recovered from E = K_b^T F K_a by cheirality on the
  evaluation matches; ``rot_err_deg`` (angle of R^T R_gt), ``trans_err_deg`` (angle between t and t_gt as
  min(e, 180 - e)), ``pose_err_deg`` = their max; NaN when no pose can be recovered;
- FM-Bench (:mod:`fviz.geometry.fmbench`): ``nsgd`` (normalized symmetric geometric distance, seeded) and
  ``gt_inlier_ratio`` (share of the inliers within 0.003 x diagonal of the ground-truth lines);
- per pair, before any estimator (``PairResult.match_precision``, :mod:`fviz.geometry.precision`): the share
  of matches under glue-factory's normalized epipolar error 1e-4 / 5e-4 / 1e-3 (``epi_prec@...``) and under
  1 / 2 / 4 px of F_gt (``px_prec@...``): whether the matcher gave an estimator something to find;
- ``f_dist``: ||F - F_gt|| of unit-norm pixel-coordinate F, up to sign. Kept per pair for continuity only:
  unconditioned (the entries of a pixel F differ by ~10^6 in scale), it misranks estimators and is used in
  no summary, table or ranking.

The ground truth itself gets the same row (``gt``): the paper's "Ground-truth" row, with the true pose.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from fviz.data.pair import Pair
from fviz.errors import FvizError
from fviz.estimators.base import Estimate, EstimateFn, run_estimator
from fviz.estimators.features import FeatureCache, FeatureConfig, Matches, match
from fviz.geometry import (
    nearest_rotation,
    NORMS,
    NormalizationError,
    algebraic,
    epipoles,
    f_distance,
    gt_inlier_ratio,
    match_precision,
    normalize,
    nsgd,
    recover_pose,
    rotation_error_deg,
    sampson_distance,
    symmetric_epipolar_distance,
    translation_error_deg,
)

GT_NAME = "gt"
EVAL_THRESHOLD_PX = 2.0
MIN_MATCHES = 8


@dataclass
class EstimatorResult:
    """One estimator on one pair. ``residuals_px``: SED of every match (for plots), not serialised.
    ``R``, ``t``: the recovered relative pose (X_b = R X_a + t, |t| = 1), None when unknown."""

    name: str
    F: np.ndarray | None
    metrics: dict[str, float]
    seconds: float
    error: str | None = None
    inliers: np.ndarray | None = None
    residuals_px: np.ndarray | None = None
    R: np.ndarray | None = None
    t: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "F": None if self.F is None else self.F.tolist(),
            "R": None if self.R is None else self.R.tolist(),
            "t": None if self.t is None else self.t.tolist(),
            "metrics": {k: _json_float(v) for k, v in self.metrics.items()},
            "seconds": self.seconds,
            "error": self.error,
        }


@dataclass
class PairResult:
    """Everything ``inspect pair`` shows of one pair; the JSON, CSV rows and recording all come from it."""

    pair: dict[str, Any]
    norm: str
    eval_threshold_px: float
    F_gt: np.ndarray
    n_keypoints: tuple[int, int]
    n_matches: int
    n_eval: int
    timings: dict[str, float]
    estimators: list[EstimatorResult]
    matches: Matches | None = None
    eval_mask: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    match_precision: dict[str, float] = field(default_factory=dict)

    @property
    def errors(self) -> list[str]:
        return [f"{r.name}: {r.error}" for r in self.estimators if r.error]

    def get(self, name: str) -> EstimatorResult | None:
        return next((r for r in self.estimators if r.name == name), None)

    def to_dict(self) -> dict[str, Any]:
        return {
            "pair": self.pair,
            "norm": self.norm,
            "metric_note": "epi_abs/epi_sqr are means per pair over evaluation correspondences, on F normalized by 'norm'",
            "eval_threshold_px": self.eval_threshold_px,
            "F_gt": self.F_gt.tolist(),
            "n_keypoints": list(self.n_keypoints),
            "n_matches": self.n_matches,
            "n_eval": self.n_eval,
            "timings": self.timings,
            "estimators": [r.to_dict() for r in self.estimators],
            "notes": self.notes,
            "match_precision": {k: _json_float(v) for k, v in self.match_precision.items()},
        }

    def rows(self) -> list[dict[str, Any]]:
        """Flat rows (one per estimator) for CSV / Parquet."""
        base = {k: v for k, v in self.pair.items() if not isinstance(v, (list, dict))}
        return [
            {**base, "estimator": r.name, "norm": self.norm, "n_matches": self.n_matches, "n_eval": self.n_eval,
             **self.match_precision, "seconds": r.seconds, "error": r.error or "", **r.metrics}
            for r in self.estimators
        ]


def _json_float(v: float) -> float | None:
    v = float(v)
    return v if np.isfinite(v) else None


def _ray_angle_deg(K: np.ndarray, e1: np.ndarray, e2: np.ndarray) -> float:
    r1, r2 = np.linalg.solve(K, e1), np.linalg.solve(K, e2)
    c = abs(r1 @ r2) / (np.linalg.norm(r1) * np.linalg.norm(r2))
    return float(np.degrees(np.arccos(np.clip(c, 0.0, 1.0))))


def epi_metrics(F: np.ndarray, x_a: np.ndarray, x_b: np.ndarray, norm: str) -> tuple[float, float]:
    """(EPI-ABS, EPI-SQR) as means over the given correspondences of F normalized by ``norm``."""
    if len(x_a) == 0:
        return float("nan"), float("nan")
    try:
        r = algebraic(normalize(F, norm), x_a, x_b)
    except NormalizationError:
        return float("nan"), float("nan")
    return float(r.mean()), float((r**2).mean())


def pose_metrics(R: np.ndarray | None, t: np.ndarray | None, pair: Pair) -> dict[str, float]:
    """rot_err_deg, trans_err_deg and pose_err_deg (their max) of a recovered pose; NaN without one."""
    if R is None:
        return dict.fromkeys(("rot_err_deg", "trans_err_deg", "pose_err_deg"), float("nan"))
    R_gt, t_gt = true_pose(pair)
    rot, trans = float(rotation_error_deg(R, R_gt)), float(translation_error_deg(t, t_gt))
    return {"rot_err_deg": rot, "trans_err_deg": trans, "pose_err_deg": max(rot, trans)}


def true_pose(pair: Pair) -> tuple[np.ndarray, np.ndarray]:
    """(R, t / |t|) of the pair's ground-truth motion, R projected onto the rotations (:func:`nearest_rotation`)."""
    n = np.linalg.norm(pair.t)
    return nearest_rotation(pair.R), np.asarray(pair.t, np.float64) / (n if n > 0 else 1.0)


def score(
    name: str, F: np.ndarray, pair: Pair, m: Matches, eval_mask: np.ndarray, norm: str,
    inliers: np.ndarray | None, threshold_px: float,
) -> tuple[dict[str, float], np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
    """Metrics of one F on one pair (see module doc), per-match SED residuals (px), the inlier mask and
    the recovered pose (None when unknown; the true one for the ground truth).

    Without an estimator's own mask, inliers are the matches with Sampson distance < ``threshold_px``.
    """
    sed = symmetric_epipolar_distance(F, m.x_a, m.x_b)
    xa, xb = m.x_a[eval_mask], m.x_b[eval_mask]
    samp = sampson_distance(F, xa, xb)
    if inliers is None:
        inliers = sampson_distance(F, m.x_a, m.x_b) < threshold_px
    ea, eb = epipoles(F)
    ga, gb = epipoles(pair.F_gt)
    nan = float("nan")
    metrics: dict[str, float] = {}
    metrics["epi_abs"], metrics["epi_sqr"] = epi_metrics(F, xa, xb, norm)
    for n in NORMS:
        metrics[f"epi_abs_{n}"], metrics[f"epi_sqr_{n}"] = epi_metrics(F, xa, xb, n)
    metrics.update(
        sed_mean=float(np.mean(sed[eval_mask])) if eval_mask.any() else nan,
        sed_median=float(np.median(sed[eval_mask])) if eval_mask.any() else nan,
        sampson_mean=float(samp.mean()) if len(samp) else nan,
        sampson_median=float(np.median(samp)) if len(samp) else nan,
        n_inliers=float(inliers.sum()),
        inlier_ratio=float(inliers.mean()) if len(inliers) else nan,
        f_dist=float(f_distance(F, pair.F_gt)),
        epipole_err_deg=max(_ray_angle_deg(pair.K_a, ea, ga), _ray_angle_deg(pair.K_b, eb, gb)),
    )
    if name == GT_NAME:
        pose = true_pose(pair)
        metrics.update(rot_err_deg=0.0, trans_err_deg=0.0, pose_err_deg=0.0)
    else:
        pose = recover_pose(F, pair.K_a, pair.K_b, xa, xb)
        metrics.update(pose_metrics(*(pose or (None, None)), pair))
    metrics["nsgd"] = 0.0 if name == GT_NAME else nsgd(F, pair.F_gt, pair.size_a, pair.size_b)
    metrics["gt_inlier_ratio"] = gt_inlier_ratio(pair.F_gt, m.x_a, m.x_b, inliers, pair.size_a, pair.size_b)
    return metrics, sed, inliers, pose


def evaluate_pair(
    pair: Pair,
    estimators: Sequence[tuple[str, EstimateFn]],
    features: FeatureConfig = FeatureConfig(),
    norm: str = "fbn",
    eval_threshold_px: float = EVAL_THRESHOLD_PX,
    inlier_threshold_px: float = 1.0,
    cache: FeatureCache | None = None,
    timeout: float | None = None,
) -> PairResult:
    """Detect, match, run every estimator (isolated, at most ``timeout`` s each: see
    :func:`fviz.estimators.base.run_estimator`), and score it against the ground truth."""
    if norm not in NORMS:
        raise FvizError(f"--norm {norm!r}: choose one of {', '.join(NORMS)}")
    cache = cache or FeatureCache(features)
    t0 = time.perf_counter()
    fa, fb = cache.get_pair(pair.id.key_a, pair.image_a, pair.id.key_b, pair.image_b)
    t1 = time.perf_counter()
    m = match(fa, fb, features)
    t2 = time.perf_counter()
    gt_sed = symmetric_epipolar_distance(pair.F_gt, m.x_a, m.x_b)
    eval_mask = gt_sed < eval_threshold_px
    notes = list(pair.notes)
    if norm == "etr" and abs(normalize(pair.F_gt, "fbn")[2, 2]) < 1e-9:
        notes.append("ETR is undefined for this pair (F33 = 0: rectified stereo); epi_* under ETR are NaN")
    results = []
    for name, fn in [(GT_NAME, lambda p, a, b: p.F_gt), *estimators]:
        est: Estimate = run_estimator(name, fn, pair, m.x_a, m.x_b, timeout)
        if not est.ok:
            results.append(EstimatorResult(name, None, {}, est.seconds, est.error))
            continue
        inliers = est.inliers if name != GT_NAME else None
        metrics, sed, inl, pose = score(name, est.F, pair, m, eval_mask, norm, inliers, inlier_threshold_px)
        R, t = pose or (None, None)
        results.append(EstimatorResult(name, est.F, metrics, est.seconds, None, inl, sed, R, t))
    return PairResult(
        pair=pair.to_dict(), norm=norm, eval_threshold_px=eval_threshold_px, F_gt=pair.F_gt,
        n_keypoints=(len(fa.keypoints), len(fb.keypoints)), n_matches=len(m), n_eval=int(eval_mask.sum()),
        timings={"features_s": t1 - t0, "matching_s": t2 - t1}, estimators=results, matches=m,
        eval_mask=eval_mask, notes=notes,
        match_precision={} if pair.F_gt is None else match_precision(pair.K_a, pair.K_b, pair.R, pair.t, pair.F_gt,
                                                                     m.x_a, m.x_b),
    )
