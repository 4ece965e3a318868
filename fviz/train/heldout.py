"""Held-out figures of an estimator, as ``fviz eval`` computes them, over KITTI pairs it never trained on.

Per pair, :func:`fviz.evaluate.evaluate_pair` (SIFT matches, the evaluation matches within 2 px of the
ground truth, FBN EPI-ABS / EPI-SQR, median SED, epipole error, and the pose errors ``rot_err_deg`` /
``trans_err_deg`` / ``pose_err_deg`` of the pose recovered by cheirality on the evaluation matches): every key
means what it means in ``fviz eval``. On top, one figure of its own:

- yaw (deg, about the camera's y axis) of the decomposed rotation closer to identity, and its Pearson
  correlation with the ground-truth yaw over the temporal pairs;
- straight driving: temporal pairs with |GT yaw| < ``STRAIGHT_YAW_DEG``.

Summary figures (:func:`summarize`) are medians over pairs, split by pair kind:
``temporal_sed_median``, ``temporal_rot_err_median``, ``temporal_yaw_corr``, ``temporal_yaw_slope`` (least
squares, predicted on true yaw: 1 follows the car, 0 ignores it), ``straight_sed_median``,
``stereo_epipole_err_median``, ``stereo_sed_median``, the paper's Table 1 means ``epi_abs`` /
``epi_sqr`` (FBN) over all pairs, and the standard figure ``fviz eval`` prints first, ``pose_auc`` (AUC@5/10/20 of
the eval's ``pose_err_deg`` over all pairs, :func:`fviz.geometry.pose_auc`: a pair without a pose counts as a miss).

:func:`heldout_report` (``heldout.json`` of ``fviz train``) sets the model beside two constants that read no
image, the straight-ahead F (``constant``) and the mean ground-truth F of the recipe's training pairs (``mean_f``),
and gives the paired test of the model against each (:func:`paired_test`: ``fviz compare``'s wins, losses,
ties and Wilcoxon signed-rank test) on ``pose_err_deg``, ``sed_median`` and ``rot_err_deg``.  ``beats``: whether
the paired pose-error test finds the model better than each constant (:func:`beats_constant`); ``verdict``: one
line, "the model is no better than the constant: ..." unless it beats both, every figure beside both constants'
(:func:`heldout_verdict`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from fviz.geometry.pose import yaw_deg

STRAIGHT_YAW_DEG = 0.2


def yaw_of_f(F: np.ndarray, K_a: np.ndarray, K_b: np.ndarray) -> float:
    """Yaw of the rotation of E closer to identity (driving: frame-to-frame rotations are small)."""
    from fviz.geometry.pose import small_motion

    return float(yaw_deg(small_motion(F, K_a, K_b)[0]))


def straight_ahead_f(pair, x_a=None, x_b=None) -> np.ndarray:
    """The straight-ahead constant: R = I, t along the optical axis (an estimator: ignores the matches)."""
    from fviz.geometry import fundamental_from_motion

    return fundamental_from_motion(pair.K_a, pair.K_b, np.eye(3), np.array([0.0, 0.0, -1.0]))


@dataclass
class PairFigures:
    name: str
    kind: str
    gt_yaw: float
    metrics: dict[str, float]  # the eval's metrics of the estimator on this pair, plus yaw_deg


def pair_figures(pair, estimators: list[tuple[str, Callable]], cache=None) -> dict[str, PairFigures]:
    """Figures of every estimator on one pair: {name: PairFigures}, the eval's metrics and ``yaw_deg`` (an
    estimator that fails gets NaNs)."""
    from fviz.evaluate import evaluate_pair

    result = evaluate_pair(pair, estimators, cache=cache)
    out = {}
    for est in result.estimators:
        m = dict.fromkeys(("rot_err_deg", "pose_err_deg", "sed_median", "epipole_err_deg"), math.nan) | est.metrics
        m["yaw_deg"] = yaw_of_f(est.F, pair.K_a, pair.K_b) if est.F is not None else math.nan
        out[est.name] = PairFigures(pair.id.name, pair.id.kind, float(yaw_deg(pair.R)), m)
    return out


def _median(values: list[float]) -> float:
    v = np.asarray([x for x in values if x is not None], dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else math.nan


def summarize(rows: list[PairFigures]) -> dict[str, Any]:
    """Summary figures of one estimator over its pairs (see the module docstring)."""
    from fviz.geometry import AUC_THRESHOLDS_DEG, pose_auc

    temporal = [r for r in rows if r.kind == "temporal"]
    stereo = [r for r in rows if r.kind == "stereo"]
    straight = [r for r in temporal if abs(r.gt_yaw) < STRAIGHT_YAW_DEG]
    yaw_p = np.array([r.metrics.get("yaw_deg", math.nan) for r in temporal])
    yaw_g = np.array([r.gt_yaw for r in temporal])
    ok = np.isfinite(yaw_p)
    corr = slope = math.nan
    if ok.sum() >= 3 and np.std(yaw_p[ok]) > 0 and np.std(yaw_g[ok]) > 0:
        corr = float(np.corrcoef(yaw_p[ok], yaw_g[ok])[0, 1])
        slope = float(np.polyfit(yaw_g[ok], yaw_p[ok], 1)[0])  # predicted yaw per degree of true yaw
    epi = [r.metrics.get("epi_abs_fbn", math.nan) for r in rows]
    epi_sq = [r.metrics.get("epi_sqr_fbn", math.nan) for r in rows]
    return {
        "pairs": len(rows), "temporal_pairs": len(temporal), "straight_pairs": len(straight), "stereo_pairs": len(stereo),
        "temporal_sed_median": _median([r.metrics.get("sed_median") for r in temporal]),
        "temporal_rot_err_median": _median([r.metrics.get("rot_err_deg") for r in temporal]),
        "temporal_yaw_corr": corr,
        "temporal_yaw_slope": slope,
        "straight_sed_median": _median([r.metrics.get("sed_median") for r in straight]),
        "stereo_epipole_err_median": _median([r.metrics.get("epipole_err_deg") for r in stereo]),
        "stereo_sed_median": _median([r.metrics.get("sed_median") for r in stereo]),
        "epi_abs": float(np.nanmean(epi)) if np.isfinite(epi).any() else math.nan,
        "epi_sqr": float(np.nanmean(epi_sq)) if np.isfinite(epi_sq).any() else math.nan,
        "pose_auc": {f"{t:g}": a for t, a in zip(AUC_THRESHOLDS_DEG,
                                                 pose_auc([r.metrics.get("pose_err_deg", math.nan) for r in rows]))},
    }


PAIRED_METRICS = ("pose_err_deg", "sed_median", "rot_err_deg")


def paired_test(a: list[PairFigures], b: list[PairFigures], metric: str, names: tuple[str, str] = ("a", "b")) -> dict[str, Any]:
    """``fviz compare`` of two estimators' per-pair figures on ``metric`` (:func:`fviz.compare.compare_values`):
    pairs compared, wins (a better), losses, ties (within 5 %), failures, the median of a - b and Wilcoxon's
    signed-rank p (two-sided), and ``verdict``: "a better" / "b better" where p < 0.05, else "no difference shown"."""
    from pathlib import Path

    from fviz.compare import Side, _median_diff, compare_values
    from fviz.verdicts import HIGHER_IS_BETTER

    def side(rows):
        return {r.name: (float(r.metrics.get(metric, math.nan)), "") for r in rows}

    c = compare_values(Side(Path("heldout"), names[0]), Side(Path("heldout"), names[1]), metric, side(a), side(b))
    w = c.wilcoxon()
    median = _median_diff(c)
    a_ahead = (median > 0) if metric in HIGHER_IS_BETTER else (median < 0)
    better = (names[0] if a_ahead else names[1]) if w.n and w.p < 0.05 else ""
    return {"metric": metric, "pairs": len(c.values), "wins": len(c.wins), "losses": len(c.losses), "ties": len(c.ties),
            "a_errors": len(c.a_errors), "b_errors": len(c.b_errors), "median_a_minus_b": median,
            "wilcoxon_p": w.p, "wilcoxon_method": w.method, "wilcoxon_n": w.n,
            "verdict": f"{better} better" if better else "no difference shown"}


def evaluate_heldout(pairs, estimators: list[tuple[str, Callable]], on_pair=None) -> dict[str, dict[str, Any]]:
    """{estimator (and "gt"): summary} over ``pairs`` (an iterable of :class:`fviz.data.pair.Pair`)."""
    return {name: summarize(r) for name, r in heldout_rows(pairs, estimators, on_pair).items()}


def heldout_rows(pairs, estimators: list[tuple[str, Callable]], on_pair=None) -> dict[str, list[PairFigures]]:
    """{estimator (and "gt"): its per-pair figures} over ``pairs``."""
    from fviz.estimators.features import FeatureCache, FeatureConfig

    cache = FeatureCache(FeatureConfig())
    rows: dict[str, list[PairFigures]] = {}
    for n, pair in enumerate(pairs):
        for name, fig in pair_figures(pair, estimators, cache).items():
            rows.setdefault(name, []).append(fig)
        if on_pair is not None:
            on_pair(n + 1)
    return rows


def fit_yaw_gain(model, pairs, gains=tuple(np.round(np.arange(1.0, 2.001, 0.05), 2))) -> tuple[float, dict[float, float]]:
    """The gain on the yaw of ``model``'s mean motion (:func:`fviz.models.predict.predict_F` with the
    pair's cameras) that gives the lowest median rotation error over ``pairs`` (training pairs with poses,
    never the held-out ones), and {gain: median rotation error, deg}.  A network that regresses F shrinks
    its yaw towards the mean of what it saw (slope 0.42 on odometry 00); its yaw is scaled back, pitch and
    roll are kept (:func:`fviz.geometry.scale_yaw`)."""
    from fviz.geometry.pose import nearest_rotation, rotation_error_deg, scale_yaw, small_motion
    from fviz.models.predict import predict_F

    motions, truths = [], []
    for pair in pairs:
        F = predict_F(model, pair.image_a, pair.image_b, (pair.K_a, pair.K_b))
        motions.append(small_motion(F, pair.K_a, pair.K_b)[0])
        truths.append(nearest_rotation(pair.R))
    if not motions:
        raise ValueError("fit_yaw_gain: no pairs")
    errors = {float(g): float(np.median([rotation_error_deg(scale_yaw(R, g), R_gt) for R, R_gt in zip(motions, truths)]))
              for g in gains}
    return min(errors, key=errors.get), errors


def heldout_pairs(recipe, directions: bool = False):
    """The recipe's held-out pairs (``data.val_sequences``), forward direction only unless ``directions``."""
    from fviz.train.data import load_kitti_pair
    from fviz.train.splits import kitti_items, open_named, resolve_root

    d = recipe.data
    roots = [str(resolve_root(r)) for r in [d.root, *d.roots] if r]
    for name in d.val_sequences:
        _, ds = open_named(roots, name)
        for item in kitti_items(recipe, name):
            if item.reverse and not directions:
                continue
            yield load_kitti_pair(ds, item)


def training_mean_f(recipe) -> dict[str, np.ndarray]:
    """{pair kind: the mean ground-truth F (:func:`fviz.estimators.baselines.mean_fundamental`) of the recipe's
    training pairs of that kind}, forward direction, from calibration and poses alone (no image read); a kind
    without a pair with F is left out."""
    from fviz.estimators.baselines import mean_fundamental
    from fviz.errors import FvizError
    from fviz.train.data import kitti_pair_id
    from fviz.train.splits import kitti_items, open_named, resolve_root

    d = recipe.data
    roots = [str(resolve_root(r)) for r in [d.root, *d.roots] if r]
    truths: dict[str, list[np.ndarray]] = {}
    for name in [*d.sequences, *d.drives]:
        _, ds = open_named(roots, name)
        for item in kitti_items(recipe, name):
            if item.reverse:
                continue
            try:
                truths.setdefault(item.kind, []).append(ds.ground_truth(kitti_pair_id(ds, item))[4])
            except FvizError:  # a pair without motion has no F
                continue
    return {kind: mean_fundamental(Fs) for kind, Fs in truths.items() if Fs}


def mean_f_estimator(means: dict[str, np.ndarray]):
    """The constant of the pair's kind (:func:`training_mean_f`); NaN F (a failure) for a kind it has none of."""

    def constant(pair, x_a=None, x_b=None):
        F = means.get(pair.id.kind)
        if F is None:
            raise ValueError(f"no training pair of kind {pair.id.kind}: no mean F")
        return F.copy()

    return constant


def heldout_report(recipe, weights) -> dict[str, Any]:
    """The held-out figures of a trained model file over the recipe's ``data.val_sequences`` (forward pairs
    of every selected kind and step): what ``-e deep:PATH`` gives a user on sequences the model never trained
    on, beside two constants that read no image, the straight-ahead F (``constant``) and the mean ground-truth
    F of the training pairs (``mean_f``), with the paired test of the model against each on pose error, SED
    and rotation error (``paired``: {constant name: {metric: :func:`paired_test`}}; ``per_pair``: the figures
    tested, {estimator: {pair: {metric: value}}}). ``chose`` says what the
    held-out sequences selected: they are the validation set, so with ``train.keep_best`` they chose the
    checkpoint. {} when the recipe names no held-out KITTI sequence."""
    if recipe.data.source == "synthetic" or not recipe.data.val_sequences:
        return {}
    from fviz.estimators.deep import deep_estimator

    pairs = list(heldout_pairs(recipe))
    estimators = [("model", deep_estimator(weights)), ("constant", straight_ahead_f)]
    means = training_mean_f(recipe)
    if means:
        estimators.append(("mean_f", mean_f_estimator(means)))
    rows = heldout_rows(pairs, estimators)
    keep_best = recipe.train.keep_best
    report: dict[str, Any] = {
        "sequences": list(recipe.data.val_sequences),
        "trained_on": [*recipe.data.sequences, *recipe.data.drives],
        "chose": (f"the checkpoint (validation set; train.keep_best = {keep_best!r})" if keep_best
                  else "nothing selected by the training run (validation curves only; model.pt is the last step)"),
        **{name: summarize(rows[name]) for name, _ in estimators},
        "paired": {},
    }
    report["per_pair"] = {name: {r.name: {m: r.metrics.get(m, math.nan) for m in PAIRED_METRICS} for r in rows[name]}
                          for name, _ in estimators}
    for other in [name for name, _ in estimators[1:]]:
        report["paired"][other] = {m: paired_test(rows["model"], rows[other], m, ("model", other)) for m in PAIRED_METRICS}
    report["beats"] = {other: beats_constant(report, other) for other in report["paired"]}
    report["verdict"] = heldout_verdict(report)
    return report


CONSTANT_NAMES = {"constant": "straight-ahead motion", "mean_f": "the training pairs' mean F"}
NO_BETTER = "the model is no better than the constant"  # the verdict held out and at each validation (fviz.train.validation)


def beats_constant(report: dict[str, Any], other: str, metric: str = "pose_err_deg") -> bool:
    """Whether the held-out report's paired test finds the model better than the constant ``other`` on ``metric``
    (Wilcoxon p < 0.05, the model's errors lower): where it does not, the model is no better than the constant."""
    return (report.get("paired", {}).get(other, {}).get(metric, {}).get("verdict") == "model better")


def heldout_verdict(report: dict[str, Any]) -> str:
    """One line: "the model beats both constants: ..." or "the model is no better than the constant: held-out 04, 10:
    pose AUC@5/10/20 a/b/c, median temporal SED x px vs ... for straight-ahead motion (paired pose error: ...) and
    ... for the training pairs' mean F (...)", every figure beside the model's; "" without constants."""
    others = [o for o in ("constant", "mean_f") if o in report.get("paired", {}) and o in report]
    if "model" not in report or not others:
        return ""

    def figures(name: str) -> str:
        f = report[name]
        auc = "/".join(f"{v:.3g}" for v in f.get("pose_auc", {}).values())
        return f"pose AUC@5/10/20 {auc}, temporal median SED {f.get('temporal_sed_median', math.nan):.3g} px"

    def tested(o: str) -> str:
        t = report["paired"][o].get("pose_err_deg", {})
        return (f"paired pose error {t.get('wins')} wins, {t.get('losses')} losses, "
                f"p {t.get('wilcoxon_p', math.nan):.2g}: {t.get('verdict')}")

    lost = [o for o in others if not beats_constant(report, o)]
    head = NO_BETTER if lost else f"the model beats {'both constants' if len(others) > 1 else 'the constant'}"
    beside = " and ".join(f"{figures(o)} for {CONSTANT_NAMES[o]} ({tested(o)})" for o in others)
    return f"{head}: held-out {', '.join(report.get('sequences', []))}: model {figures('model')} vs {beside}"
