"""The paper's protocol (Sec. 4.1) for one pair -> one plain result object.

Evaluation correspondences are the matched keypoints whose symmetric epipolar distance to the
*ground-truth* F (the mean of the two point-to-line distances) is below ``eval_threshold_px`` (2 px). The paper's
rule is stricter: the *sum of the squared* distances below 2 (px^2), within about one pixel of the line
(:func:`near_ground_truth`, rule "paper"; ``fviz table`` and benchmarks/paper_table1.py use it for Table 1 in the
paper's frame). On them, per estimator:

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

Ground truth is optional (:attr:`Pair.has_gt`). Without it there is no ``gt`` row and every GT-based metric
(f_dist, nsgd, gt_inlier_ratio, epipole_err_deg, the pose errors) is absent, not NaN; the residuals are
taken over all matches, and the estimators are compared with each other: ``agreement_nsgd`` is the NSGD of an
estimator's F to the closest other estimator's (``PairResult.agreement`` holds the whole matrix and the groups of
estimators that agree: NSGD < NSGD_RECALL_THRESHOLD, see :func:`agreement_text`).
With an F but no pose (``--F-gt``, ``--gt-matches``) the pose errors are absent; without cameras (K) the
pose is not recovered and epipole_err_deg is absent. With ground-truth correspondences (``pair.gt_points``)
the residuals are computed on them (``eval_points`` = "gt-matches") rather than on the matches near F_gt.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from fviz.data.pair import Pair
from fviz.errors import FvizError
from fviz.estimators.base import Estimate, EstimateFn, run_estimator
from fviz.estimators.features import FeatureCache, FeatureConfig, Features, Matches, match, user_matches
from fviz.geometry import (
    NSGD_RECALL_THRESHOLD,
    nearest_rotation,
    NORMS,
    NormalizationError,
    algebraic,
    apply_homography,
    epipolar_residuals,
    epipoles,
    f_distance,
    gt_inlier_ratio,
    match_precision,
    normalize,
    nsgd,
    recover_pose,
    rotation_error_deg,
    squared_epipolar_distances,
    symmetric_epipolar_distance,
    transfer_fundamental,
    translation_error_deg,
)

GT_NAME = "gt"
EVAL_THRESHOLD_PX = 2.0
EVAL_RULES = ("fviz", "paper")  # which matches are scored: see near_ground_truth
READINGS = ("unrectified", "rectified-pixels")  # where another frame's ground truth is scored: see rows_in_frame
MIN_MATCHES = 8  # what most estimators need; 7point and PoseLib work from 7 (see too_few_matches)


def metric_unit(key: str) -> str:
    """The unit a metric is in ("px", "deg" or "")."""
    return "px" if key.startswith(("sed", "sampson")) else "deg" if key.endswith("_deg") else ""


def too_few_matches(result) -> bool:
    """Whether the pair fails as a whole for want of matches: fewer than MIN_MATCHES and no estimator made an F
    of them (7 matches are enough for 7point and PoseLib: then only the estimators that need more fail)."""
    return result.n_matches < MIN_MATCHES and not any(
        r.F is not None and not r.error for r in result.estimators if r.name != GT_NAME)


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
    F_gt: np.ndarray | None
    n_keypoints: tuple[int, int]
    n_matches: int
    n_eval: int
    timings: dict[str, float]
    estimators: list[EstimatorResult]
    matches: Matches | None = None
    eval_mask: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    match_precision: dict[str, float] = field(default_factory=dict)
    eval_points: str = "near-gt"  # what the residuals are computed on: near-gt, gt-matches or all-matches
    agreement: dict[str, Any] | None = None  # without ground truth: {"metric": "nsgd", "names", "matrix"}
    verdict: Any = None  # fviz.verdicts.Verdict, set by fviz.inspect_pair

    @property
    def has_gt(self) -> bool:
        return self.F_gt is not None

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
            "F_gt": None if self.F_gt is None else self.F_gt.tolist(),
            "ground_truth": self.pair.get("ground_truth", "pose"),
            "eval_points": self.eval_points,
            **({} if self.agreement is None else {"agreement": self.agreement}),
            "n_keypoints": list(self.n_keypoints),
            "n_matches": self.n_matches,
            "n_eval": self.n_eval,
            "timings": self.timings,
            "estimators": [r.to_dict() for r in self.estimators],
            "notes": self.notes,
            "match_precision": {k: _json_float(v) for k, v in self.match_precision.items()},
            **({} if self.verdict is None else {"verdict": {"kind": self.verdict.kind, "text": self.verdict.text}}),
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
    # atan2, not arccos of the cosine: exact (0) for one ray twice, accurate for small angles
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(r1, r2)), abs(r1 @ r2))))


def epi_metrics(F: np.ndarray, x_a: np.ndarray, x_b: np.ndarray, norm: str) -> tuple[float, float]:
    """(EPI-ABS, EPI-SQR) as means over the given correspondences of F normalized by ``norm``."""
    return _epi_of(algebraic(F, x_a, x_b), F, norm)


def _epi_of(residuals: np.ndarray, F: np.ndarray, norm: str) -> tuple[float, float]:
    """:func:`epi_metrics` from F's own algebraic residuals |x_b^T F x_a| (N,): normalizing F scales them."""
    if len(residuals) == 0:
        return float("nan"), float("nan")
    F = np.asarray(F, np.float64)
    try:
        scale = abs(float(np.sum(normalize(F, norm) * F) / np.sum(F * F)))  # normalize(F) = +-scale F
    except NormalizationError:
        return float("nan"), float("nan")
    r = residuals * scale
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
    name: str, F: np.ndarray, pair: Pair, m: Matches, evaluation: tuple[np.ndarray, np.ndarray], norm: str,
    inliers: np.ndarray | None, threshold_px: float, eval_mask: np.ndarray | None = None,
) -> tuple[dict[str, float], np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
    """Metrics of one F on one pair (see module doc), per-match SED residuals (px), the inlier mask and
    the recovered pose (None when unknown; the true one for the ground truth).

    evaluation: (x_a, x_b) (E, 2) the points the residuals are computed on (:func:`evaluation_points`);
    ``eval_mask`` (M,) when they are the matches under it (their residuals are then taken, not recomputed).
    Without an estimator's own mask, inliers are the matches with Sampson distance < ``threshold_px``.
    Metrics that need what the pair lacks (ground truth, pose, cameras) are absent.
    """
    alg_m, sed, samp_m = epipolar_residuals(F, m.x_a, m.x_b)
    xa, xb = evaluation
    if eval_mask is not None:  # the evaluation points are these matches: their residuals are at hand
        alg, sed_eval, samp = alg_m[eval_mask], sed[eval_mask], samp_m[eval_mask]
    else:
        alg, sed_eval, samp = epipolar_residuals(F, xa, xb)
    if inliers is None:
        inliers = samp_m < threshold_px
    nan = float("nan")
    metrics: dict[str, float] = {}
    metrics["epi_abs"], metrics["epi_sqr"] = _epi_of(alg, F, norm)
    for n in NORMS:
        metrics[f"epi_abs_{n}"], metrics[f"epi_sqr_{n}"] = _epi_of(alg, F, n)
    metrics.update(
        sed_mean=float(np.mean(sed_eval)) if len(sed_eval) else nan,
        sed_median=float(np.median(sed_eval)) if len(sed_eval) else nan,
        sampson_mean=float(samp.mean()) if len(samp) else nan,
        sampson_median=float(np.median(samp)) if len(samp) else nan,
        n_inliers=float(inliers.sum()),
        inlier_ratio=float(inliers.mean()) if len(inliers) else nan,
    )
    if pair.has_gt:
        metrics["f_dist"] = float(f_distance(F, pair.F_gt))
    if pair.has_gt and pair.has_K:
        (ea, eb), (ga, gb) = epipoles(F), epipoles(pair.F_gt)
        metrics["epipole_err_deg"] = max(_ray_angle_deg(pair.K_a, ea, ga), _ray_angle_deg(pair.K_b, eb, gb))
    if name == GT_NAME:
        pose = true_pose(pair) if pair.has_pose else None
        if pose:
            metrics.update(rot_err_deg=0.0, trans_err_deg=0.0, pose_err_deg=0.0)
    else:
        cheirality = cheirality_points(pair, (xa, xb))
        pose = recover_pose(F, pair.K_a, pair.K_b, *cheirality) if pair.has_K and cheirality else None
        if pair.has_pose:
            metrics.update(pose_metrics(*(pose or (None, None)), pair))
            if not cheirality:
                metrics["pose_undefined"] = 1.0
    if pair.has_gt:
        metrics["nsgd"] = 0.0 if name == GT_NAME else nsgd(F, pair.F_gt, pair.size_a, pair.size_b)
        metrics["gt_inlier_ratio"] = gt_inlier_ratio(pair.F_gt, m.x_a, m.x_b, inliers, pair.size_a, pair.size_b)
    return metrics, sed, inliers, pose


def near_ground_truth(F_gt: np.ndarray, x_a: np.ndarray, x_b: np.ndarray, threshold: float = EVAL_THRESHOLD_PX,
                      rule: str = "fviz") -> np.ndarray:
    """(N,) the evaluation matches under ``rule``: "fviz", the mean of the two epipolar distances below ``threshold``
    px (fviz's evaluation everywhere); "paper", the sum of their squares below ``threshold`` px^2 (Poursaeed et al.'s
    "symmetric epipolar distance below 2": within about one pixel; about a tenth as many matches)."""
    if rule not in EVAL_RULES:
        raise FvizError(f"evaluation rule {rule!r}: choose one of {', '.join(EVAL_RULES)}")
    if rule == "paper":
        return squared_epipolar_distances(F_gt, x_a, x_b) < threshold
    return symmetric_epipolar_distance(F_gt, x_a, x_b) < threshold


def rows_in_frame(result: PairResult, H_a: np.ndarray, H_b: np.ndarray, eval_threshold_px: float = EVAL_THRESHOLD_PX,
                  rule: str = "fviz", reading: str = "unrectified") -> list[dict[str, Any]]:
    """The EPI rows of :meth:`PairResult.rows` (``estimator``, ``error``, ``n_eval``, ``epi_abs_<norm>``,
    ``epi_sqr_<norm>``) with the ground truth of other pixel coordinates x' = H x (3, 3) of each image, the mapped
    F_gt (:func:`fviz.geometry.transfer_fundamental`); e.g. rectified KITTI -> the unrectified cameras of
    ``calib_cam_to_cam.txt``, the frame of the paper's F (:func:`fviz.data.kitti.raw_cameras`). ``reading``:

    - "unrectified": every F and match is mapped there too, and the evaluation matches are chosen again there
      (:func:`near_ground_truth` under ``rule``): the paper's metric in the frame its ground truth lives in;
    - "rectified-pixels": only the ground truth is replaced; the matches and the estimates stay in the images'
      pixels, and the evaluation matches are those near the mapped F_gt there: the paper's numbers if its ground
      truth (the unrectified calibration's F) was scored on the rectified images it did not describe.

    Needs ground truth and the result's matches."""
    if result.F_gt is None or result.matches is None:
        raise FvizError(f"{result.pair['name']}: another frame's EPI needs the ground truth and the matches")
    if reading not in READINGS:
        raise FvizError(f"reading {reading!r}: choose one of {', '.join(READINGS)}")
    m, F_gt = result.matches, transfer_fundamental(result.F_gt, H_a, H_b)
    if reading == "unrectified":
        x_a, x_b, to_frame = apply_homography(H_a, m.x_a), apply_homography(H_b, m.x_b), lambda F: transfer_fundamental(F, H_a, H_b)
    else:
        x_a, x_b, to_frame = m.x_a, m.x_b, lambda F: F
    near = near_ground_truth(F_gt, x_a, x_b, eval_threshold_px, rule)
    x_a, x_b = x_a[near], x_b[near]
    base = {k: v for k, v in result.pair.items() if not isinstance(v, (list, dict))}
    rows = []
    for r in result.estimators:
        row = {**base, "estimator": r.name, "error": r.error or "", "n_eval": int(near.sum())}
        if r.F is not None:
            F = F_gt if r.name == GT_NAME else to_frame(r.F)
            for n in NORMS:
                row[f"epi_abs_{n}"], row[f"epi_sqr_{n}"] = epi_metrics(F, x_a, x_b, n)
        rows.append(row)
    return rows


def cheirality_points(pair: Pair, evaluation: tuple[np.ndarray, np.ndarray]):
    """The points that choose an F's decomposition into (R, t) by cheirality: the evaluation matches, or, with fewer
    than MIN_POSE_POINTS of them, the ground truth's own correspondences where the source knows them (synthetic
    scenes, ``--gt-matches``), never the estimate's matches; None when neither is enough: the pose is then
    *undefined* (``pose_undefined`` = 1): no failure of the F in its verdict, but the field's pose AUC counts it as an
    infinite error (the matcher gave too few matches), and the AUC over the pairs with a pose leaves it out
    (:func:`fviz.run.reports.standard_figures`)."""
    from fviz.geometry.pose import MIN_POSE_POINTS

    for x_a, x_b in (evaluation, (pair.points_a, pair.points_b), pair.gt_points or (None, None)):
        if x_a is not None and len(x_a) >= MIN_POSE_POINTS:
            return x_a, x_b
    return None


def evaluation_points(pair: Pair, m: Matches, eval_threshold_px: float) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray], str]:
    """(eval_mask (M,) over the matches, the points the residuals are computed on (x_a, x_b), what they are).

    With ground-truth correspondences: those (the mask marks the matches near F_gt, for lines and the
    probe); with an F_gt: the matches within ``eval_threshold_px`` of it (the paper's protocol); without
    ground truth: every match.
    """
    if not pair.has_gt:
        return np.ones(len(m), bool), (m.x_a, m.x_b), "all-matches"
    mask = symmetric_epipolar_distance(pair.F_gt, m.x_a, m.x_b) < eval_threshold_px
    if pair.gt_points is not None:
        return mask, pair.gt_points, "gt-matches"
    return mask, (m.x_a[mask], m.x_b[mask]), "near-gt"


def agreement(results: list[EstimatorResult], size_a, size_b) -> dict[str, Any] | None:
    """Without ground truth: NSGD between every two estimators' F (symmetric up to sampling), the groups that
    agree (:func:`agreeing_groups`) and each estimator's ``agreement_nsgd`` metric (the NSGD to the closest
    other F: a median over the others would put two agreeing robust estimators as far apart as an outlier
    among three). None for fewer than two Fs."""
    ok = [r for r in results if r.F is not None]
    if len(ok) < 2:
        return None
    n = len(ok)
    matrix = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            matrix[i, j] = matrix[j, i] = 0.5 * (nsgd(ok[i].F, ok[j].F, size_a, size_b) + nsgd(ok[j].F, ok[i].F, size_a, size_b))
    for i, r in enumerate(ok):
        r.metrics["agreement_nsgd"] = float(np.delete(matrix[i], i).min())
    names = [r.name for r in ok]
    return {"metric": "nsgd", "names": names, "matrix": matrix.tolist(), "threshold": NSGD_RECALL_THRESHOLD,
            "groups": agreeing_groups(names, matrix)}


def agreeing_groups(names: Sequence[str], matrix, threshold: float = NSGD_RECALL_THRESHOLD) -> list[list[str]]:
    """The estimators linked by NSGD < ``threshold`` (FM-Bench's "same geometry"), chained: connected groups,
    largest first (then in ``names`` order); an estimator agreeing with none is a group of its own. (N, N) matrix."""
    m = np.asarray(matrix, float)
    group = list(range(len(names)))
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if m[i, j] < threshold and group[i] != group[j]:
                old, new = max(group[i], group[j]), min(group[i], group[j])
                group = [new if g == old else g for g in group]
    members = {g: [names[i] for i in range(len(names)) if group[i] == g] for g in dict.fromkeys(group)}
    return sorted(members.values(), key=lambda g: -len(g))


def _and(names: Sequence[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def agreement_text(ag: dict[str, Any] | None) -> str:
    """Which estimators agree, with the NSGD behind it: "ransac and magsac agree (NSGD 0.015); 8point differs
    (NSGD >= 0.21 to each other F)"; "" without an agreement matrix."""
    if not ag:
        return ""
    names, m = ag["names"], np.asarray(ag["matrix"], float)
    groups = ag.get("groups") or agreeing_groups(names, m)
    if len(groups) == len(names):
        apart = min(m[i, j] for i in range(len(m)) for j in range(i + 1, len(m)))
        return f"no two estimators agree (NSGD >= {apart:.2g} between any two)"
    at = {n: i for i, n in enumerate(names)}
    parts = []
    for g in groups:
        idx = [at[n] for n in g]
        if len(g) > 1:
            worst = max(m[i, j] for i in idx for j in idx if i < j)
            parts.append(f"{_and(g)} agree (NSGD {'' if len(g) == 2 else '<= '}{worst:.2g})")
        else:
            parts.append(f"{g[0]} differs (NSGD >= {np.delete(m[idx[0]], idx[0]).min():.2g} to each other F)")
    return "; ".join(parts)


def evaluate_pair(
    pair: Pair,
    estimators: Sequence[tuple[str, EstimateFn]],
    features: FeatureConfig = FeatureConfig(),
    norm: str = "fbn",
    eval_threshold_px: float = EVAL_THRESHOLD_PX,
    inlier_threshold_px: float = 1.0,
    cache: FeatureCache | None = None,
    timeout: float | None = None,
    matcher: Callable[[Features, Features], Matches] | None = None,
    matches: Matches | None = None,
) -> PairResult:
    """Detect, match (``matcher``, default :func:`fviz.estimators.features.match`; a run's may reuse cached
    matches; ``matches`` given, an edit of a result's: neither), run every estimator (isolated, at most ``timeout`` s each: see
    :func:`fviz.estimators.base.run_estimator`), and score it against the ground truth."""
    if norm not in NORMS:
        raise FvizError(f"--norm {norm!r}: choose one of {', '.join(NORMS)}")
    cache = cache or FeatureCache(features)
    t0 = time.perf_counter()
    if matches is not None:  # an edited set (fviz.reestimate): scored as it is
        m, n_keypoints, t1 = matches, (len(matches), len(matches)), t0
    elif pair.matches is not None:  # the user's matches (--matches): no detection
        m = user_matches(pair.matches)
        n_keypoints = pair.matches.n_keypoints or (len(m), len(m))
        t1 = t0
    else:
        fa, fb = cache.get_pair(pair.id.key_a, lambda: pair.image_a, pair.id.key_b, lambda: pair.image_b)  # decoded to detect
        t1 = time.perf_counter()
        m = matcher(fa, fb) if matcher is not None else match(fa, fb, features)
        n_keypoints = (len(fa.keypoints), len(fb.keypoints))
    t2 = time.perf_counter()
    eval_mask, evaluation, eval_points = evaluation_points(pair, m, eval_threshold_px)
    notes = list(pair.notes)
    if not pair.has_gt:
        notes.append("no ground truth: the estimators are compared with each other (residuals over all matches, "
                     "agreement_nsgd: NSGD to the closest other F); no GT-based metric is computed")
    if pair.has_gt and norm == "etr" and abs(normalize(pair.F_gt, "fbn")[2, 2]) < 1e-9:
        notes.append("ETR is undefined for this pair (F33 = 0: rectified stereo); epi_* under ETR are NaN")
    results = []
    gt_row = [(GT_NAME, None)] if pair.has_gt else []
    for name, fn in [*gt_row, *estimators]:
        # the ground truth is the pair's own F: nothing to isolate
        est: Estimate = Estimate(name, pair.F_gt, None, 0.0) if fn is None else run_estimator(name, fn, pair, m.x_a, m.x_b, timeout)
        if not est.ok:
            results.append(EstimatorResult(name, None, {}, est.seconds, est.error))
            continue
        inliers = est.inliers if name != GT_NAME else None
        metrics, sed, inl, pose = score(name, est.F, pair, m, evaluation, norm, inliers, inlier_threshold_px,
                                        None if eval_points == "gt-matches" else eval_mask)
        R, t = pose or (None, None)
        results.append(EstimatorResult(name, est.F, metrics, est.seconds, None, inl, sed, R, t))
    return PairResult(
        pair=pair.to_dict(), norm=norm, eval_threshold_px=eval_threshold_px, F_gt=pair.F_gt,
        n_keypoints=n_keypoints, n_matches=len(m), n_eval=len(evaluation[0]),
        timings={"features_s": t1 - t0, "matching_s": t2 - t1}, estimators=results, matches=m,
        eval_mask=eval_mask, notes=notes, eval_points=eval_points,
        agreement=None if pair.has_gt else agreement(results, pair.size_a, pair.size_b),
        match_precision={} if not pair.has_pose else match_precision(pair.K_a, pair.K_b, pair.R, pair.t, pair.F_gt,
                                                                     m.x_a, m.x_b),
    )
