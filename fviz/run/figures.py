"""The standard figures of a run (what a reviewer compares methods by): pose AUC over every pair (SuperGlue's
convention: a failure is an infinite error) and over the pairs with a pose, NSGD recall, median SED and Sampson, errors
and fails; each row's kind (counted, failed, undefined for want of evaluation matches)."""

from __future__ import annotations

import math
from typing import Any, Iterable

import numpy as np

from fviz.evaluate import GT_NAME
from fviz.geometry.pose import MIN_POSE_POINTS
from fviz.verdicts import ERRORS, fail_rule, fails_column


def figures_known(ground_truth: set[str]) -> dict[str, bool]:
    """Which standard figures the pairs' ground truth (the rows' ``ground_truth``: pose, F, correspondences,
    none) allows: pose AUC needs a pose, NSGD recall an F. Runs that predate the column: both."""
    gts = ground_truth or {"pose"}
    return {"pose": "pose" in gts, "nsgd": bool(gts - {"none"})}


# Per pair and estimator, what the standard figures need (NaN where the estimate failed).
FIGURE_KEYS = ("pose_err_deg", "nsgd", "sed_median", "sampson_median")


UNDEFINED = "pose-undefined"  # a row's kind (row_kind) where too few evaluation matches leave its figures undefined


WITH_POSE = "pairs with a pose"  # the second pose AUC: over the pairs whose pose is defined only


UNDEFINED_COLUMN = "undefined (too few matches)"


def row_failed(est: str, error: Any, pair_error: Any) -> bool:
    """Whether an estimator's row is an error (no F): its own error or its pair's. The ground truth's row never
    is: its F does not depend on the matches (a pair with too few matches, or not evaluated, leaves its residuals
    undefined, :func:`row_kind`)."""
    return est != GT_NAME and bool(error or pair_error)


def row_kind(est: str, row: dict[str, Any], failed: bool) -> str:
    """What one CSV row gives the standard figures: the pair's ground truth (pose, F, correspondences, none), or
    UNDEFINED: an estimate whose pose could not be chosen for want of evaluation matches (``pose_undefined``; the
    field's pose AUC counts it as an infinite error, the matcher gave too few matches), or the ground truth's own
    row on a pair with fewer than MIN_POSE_POINTS evaluation matches (or not evaluated): its residuals have no
    value there, which is no failure of the ground truth. ``row``: from results (floats) or metrics.csv (text)."""
    from fviz.geometry.pose import MIN_POSE_POINTS

    gt = row.get("ground_truth") or "pose"
    if est == GT_NAME:
        try:
            n_eval = float(row.get("n_eval"))
        except (TypeError, ValueError):
            n_eval = 0.0
        few = bool(row.get("error") or row.get("pair_error")) or not n_eval >= MIN_POSE_POINTS
        return UNDEFINED if few and gt == "pose" else gt
    undefined = str(row.get("pose_undefined")) in ("1", "1.0")
    return UNDEFINED if not failed and undefined else gt


EPI_CAVEAT = (
    "EPI-ABS / EPI-SQR are algebraic residuals: their values depend on the normalization of F and on the set of "
    "pairs and matches (per pixel of epipolar distance they vary by about 100x between pairs), so compare them only "
    "within one column of one run, and rank by SED, pose error or NSGD. Under ETR (F / F33) the ground-truth row can "
    "be the worst: where the true F33 is near zero (motion nearly parallel to the image plane; exactly zero on "
    "rectified stereo, where ETR is undefined) dividing by it inflates every residual, while an estimate with a larger "
    "F33 is scaled down."
)


BASELINE_NOTE = (
    "Baselines: `ahead` is straight-ahead motion from the cameras alone; `mean-...` the mean ground-truth F of other "
    "sequences; `oracle-mean` (marked *oracle*) the mean ground-truth F of the evaluated pairs themselves: it has seen "
    "the test labels, so beating it or not says nothing about estimation skill."
)


def standard_figures(per_pair: dict[str, Iterable[float]], order: Iterable[str] | None = None,
                     known: dict[str, bool] | None = None,
                     pair_gt: dict[str, list[str]] | None = None,
                     failures: dict[str, int] | None = None) -> dict[str, dict[str, Any]]:
    """Per estimator, from its per-pair FIGURE_KEYS (flat, NaN = no value): pairs, errors (no F), fails (of
    ``sed_median``, :mod:`fviz.verdicts`: past 2 px or no value, as compare counts them), nsgd_recall (share of
    pairs with nsgd < NSGD_RECALL_THRESHOLD; failures miss), medians of the per-pair sed_median and
    sampson_median over the pairs that succeeded, whether it is an oracle, and two pose AUC@5/10/20 of
    pose_err_deg (SuperGlue's ``pose_auc``, which LightGlue and glue-factory use):

    - ``pose_auc``, the field's figure: over **every** pair with a ground-truth pose (``pose_pairs``); no F, no
      pose recovered, or a pose undefined for want of evaluation matches (``pose_undefined`` pairs: the matcher
      gave too few) is an infinite error, as SuperGlue / glue-factory count a failed estimate;
    - ``pose_auc_with_pose``: the same over the ``with_pose_pairs`` whose pose is defined only; not comparable
      with published figures, nor across matchers on hard data (a matcher that gives few matches drops its
      hard pairs).

    The ground truth's own row never fails: its errors are 0, its pose AUC is over the pairs where it has a pose
    value, and ``pose_undefined`` counts the pairs with too few evaluation matches (its residuals undefined there,
    not fails). ``known``: {"pose", "nsgd"} -> whether the pairs' ground truth allows that figure; NaN (n/a)
    where it does not. ``pair_gt``: per estimator, each pair's kind (:func:`row_kind`: pose, F,
    correspondences, none, or UNDEFINED): a pair without the ground truth a figure needs never counts as a miss
    (NSGD recall is over ``gt_pairs``). ``failures``: per estimator, the pairs it gave no F on, when a NaN may
    also mean *undefined*: those are not failures."""
    known = known or {"pose": True, "nsgd": True}
    from fviz.estimators.registry import is_oracle
    from fviz.geometry import AUC_THRESHOLDS_DEG, NSGD_RECALL_THRESHOLD, pose_auc

    sed_rule = fail_rule("sed_median")
    auc = lambda e: {f"{t:g}": a if known["pose"] else math.nan for t, a in zip(AUC_THRESHOLDS_DEG, pose_auc(e))}  # noqa: E731

    out = {}
    for est in order or per_pair:
        v = np.asarray(per_pair.get(est, []), np.float64).reshape(-1, len(FIGURE_KEYS))
        pose, nsgd_, sed, samp = v.T
        is_gt = est == GT_NAME
        errors = 0 if is_gt else int(np.isnan(sed).sum()) if failures is None else failures.get(est, 0)
        kinds = (pair_gt or {}).get(est)
        kinds = np.array(kinds if kinds is not None and len(kinds) == len(v) else ["pose"] * len(v), dtype=object)
        undefined = kinds == UNDEFINED
        has_pose = (kinds == "pose") | undefined
        has_gt = kinds != "none"
        defined = kinds == "pose"
        if is_gt:  # the reference: its pose error is 0 wherever it has one, never a miss
            has_pose &= np.isfinite(pose)
            defined &= np.isfinite(pose)
        nsgd_ = nsgd_[has_gt & ~(is_gt & np.isnan(nsgd_))]
        with np.errstate(invalid="ignore"):
            recall = float(np.mean(np.nan_to_num(nsgd_, nan=np.inf) < NSGD_RECALL_THRESHOLD)) if len(nsgd_) else math.nan
        out[est] = {
            "pairs": len(v), "errors": errors,
            "fails": int(sum(sed_rule.fails(x) for x in sed if not (is_gt and math.isnan(x)))),
            "pose_pairs": int(has_pose.sum()), "gt_pairs": int(has_gt.sum()),
            "pose_undefined": int(undefined.sum()),
            "pose_auc": auc(pose[has_pose]),
            "with_pose_pairs": int(defined.sum()),
            "pose_auc_with_pose": auc(pose[defined]),
            "nsgd_recall": recall if known["nsgd"] else math.nan,
            "sed_median": float(np.nanmedian(sed)) if np.isfinite(sed).any() else math.nan,
            "sampson_median": float(np.nanmedian(samp)) if np.isfinite(samp).any() else math.nan,
            "oracle": is_oracle(est),
        }
    return out


def figures_markdown(figures: dict[str, dict[str, Any]]) -> list[str]:
    """The standard figures as a Markdown table, with how they are computed. Where some pair's pose is undefined
    (too few evaluation matches), two more columns say so apart: the AUC over the pairs with a pose (a second,
    named figure) and the count of undefined pairs."""
    from fviz.geometry import NSGD_RECALL_THRESHOLD

    aucs = next(iter(figures.values()), {}).get("pose_auc", {})
    apart = any(f.get("pose_undefined") for f in figures.values())
    slash = "/".join(aucs)
    lines = [
        "| estimator | " + " | ".join(f"AUC@{t}°" for t in aucs)
        + (f" | AUC@{slash}° ({WITH_POSE}) | {UNDEFINED_COLUMN}" if apart else "")
        + f" | NSGD recall (<{NSGD_RECALL_THRESHOLD:g}) | median SED px | median Sampson px | {ERRORS} | {fails_column()} |",
        "|---|" + "---|" * (len(aucs) + 5 + 2 * apart),
    ]
    for est, f in figures.items():
        extra = (f" | {'/'.join(_fmt(a) for a in f['pose_auc_with_pose'].values())} | {f['pose_undefined']}/{f['pairs']}"
                 if apart else "")
        lines.append(f"| {_display(est)}{' (*oracle*)' if f['oracle'] else ''} | "
                     + " | ".join(_fmt(a) for a in f["pose_auc"].values()) + extra
                     + f" | {_fmt(f['nsgd_recall'])} | {_fmt(f['sed_median'])} | {_fmt(f['sampson_median'])} | "
                     f"{f['errors']}/{f['pairs']} | {f['fails']}/{f['pairs']} |")
    partial = [f"{_display(e)}: pose AUC over {f['pose_pairs']} and NSGD recall over {f['gt_pairs']} of {f['pairs']} pairs"
               for e, f in figures.items()
               if e != GT_NAME and (f.get("pose_pairs", f["pairs"]) < f["pairs"] or f.get("gt_pairs", f["pairs"]) < f["pairs"])]
    if partial:
        lines += ["", "Only the pairs with ground truth count in the figures (a pose for AUC, any ground truth for NSGD "
                  "recall): " + "; ".join(partial[:1]) + (" (likewise the others)" if len(partial) > 1 else "") + "."]
    if apart:
        undefined = [f"{_display(e)} {f['pose_undefined']}" for e, f in figures.items() if f.get("pose_undefined") and e != GT_NAME]
        lines += ["", f"{UNDEFINED_COLUMN[0].upper()}{UNDEFINED_COLUMN[1:]}: " + (", ".join(undefined) + " pairs. " if undefined else "")
                  + f"An estimate's pose there cannot be chosen by cheirality (fewer than {MIN_POSE_POINTS} evaluation matches "
                  "and no ground-truth points): the matcher gave too few, and the field's AUC counts it as an infinite error "
                  f"(AUC@ columns); AUC@{slash}° ({WITH_POSE}) leaves those pairs out, a second figure not comparable with "
                  "published ones. The ground truth never fails: on the pairs with too few matches (fewer than "
                  f"{MIN_POSE_POINTS} evaluation matches, or too few for any estimator) its residuals are undefined, "
                  "counted in that column, not as errors."]
    lines += [
        "",
        "Pose AUC: area under the recall curve of max(rotation error, translation-direction error) up to each threshold, "
        "over every pair with a ground-truth pose, as SuperGlue / LightGlue / glue-factory compute it ((R, t) from "
        "E = K_b^T F K_a by cheirality on the evaluation matches; an error (no F), no pose recovered or a pose undefined "
        "counts as an infinite error). NSGD recall: share of pairs whose FM-Bench normalized symmetric "
        "geometric distance is below the threshold (an error is a miss). Medians: of the per-pair median over the "
        "evaluation matches, over the pairs where the estimator gave an F. Fails: past the column's threshold or no value, "
        "the pairs `fviz compare` counts as fails. " + BASELINE_NOTE,
    ]
    return lines


def _fmt(v: float) -> str:
    return "n/a" if not math.isfinite(v) else f"{v:.4g}"


def _display(est: str) -> str:
    return "ground truth" if est == GT_NAME else est
