"""One vocabulary of failure across eval, triage, compare and table (issue 28 §2), two words never swapped:

- an estimator's **error**: it gave no F on a pair (it raised, timed out, returned nothing valid), or the pair
  itself could not be evaluated (a **pair error**); the ``errors (no F)`` columns, summary.json's ``errors`` and
  :mod:`fviz.failures` count these;
- an estimate **fails** a metric: it has a value worse than that metric's threshold below (``sed_median > 2 px``),
  each metric with its own meaning; compare counts these, eval's ``fails`` column the pairs failing
  ``sed_median`` (an error, having no value, fails every metric).

A metric without an entry has no threshold: only a failed estimate (no value) fails it, unless ``compare
--fail-threshold`` gives one. ``fails_label`` names the rule wherever a count of "fails" is shown.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fviz.evaluate import EVAL_THRESHOLD_PX
from fviz.geometry import NSGD_RECALL_THRESHOLD


@dataclass(frozen=True)
class FailRule:
    """A metric fails a pair past ``threshold``: above it, or below it where higher is better."""

    threshold: float
    higher_is_better: bool = False
    unit: str = ""

    def fails(self, value: float) -> bool:
        if not math.isfinite(value):
            return True
        return value < self.threshold if self.higher_is_better else value > self.threshold


POSE_FAIL_DEG = 10.0  # the middle of the pose-AUC thresholds (5, 10, 20 deg)
LOW_INLIER_RATIO = 0.5

FAIL_RULES: dict[str, FailRule] = {
    **{k: FailRule(EVAL_THRESHOLD_PX, unit="px") for k in ("sed_median", "sed_mean", "sampson_median", "sampson_mean")},
    **{k: FailRule(POSE_FAIL_DEG, unit="deg") for k in ("pose_err_deg", "rot_err_deg", "trans_err_deg", "epipole_err_deg")},
    "nsgd": FailRule(NSGD_RECALL_THRESHOLD),  # FM-Bench's recall threshold: eval's "NSGD recall" counts the others
    "agreement_nsgd": FailRule(NSGD_RECALL_THRESHOLD),
    "inlier_ratio": FailRule(LOW_INLIER_RATIO, higher_is_better=True),  # triage's low-inliers
    "gt_inlier_ratio": FailRule(LOW_INLIER_RATIO, higher_is_better=True),
}
HIGHER_IS_BETTER = frozenset({"inlier_ratio", "n_inliers", "gt_inlier_ratio"})


def fail_rule(metric: str, threshold: float | None = None) -> FailRule | None:
    """The metric's rule; ``threshold`` (``compare --fail-threshold``) replaces its threshold, or gives one."""
    rule = FAIL_RULES.get(metric)
    if threshold is None:
        return rule
    from fviz.record.layout import metric_unit

    return FailRule(threshold, metric in HIGHER_IS_BETTER, rule.unit if rule else metric_unit(metric))


def fails(metric: str, value: float, error: str = "", threshold: float | None = None) -> bool:
    """Whether an estimate fails ``metric`` on a pair: it failed (``error``, no value) or is past the threshold."""
    if error or not math.isfinite(value):
        return True
    rule = fail_rule(metric, threshold)
    return rule is not None and rule.fails(value)


ERRORS = "errors (no F)"  # the column counting an estimator's errors, wherever one is shown
ERROR = "error"  # a value that an error left empty


def fails_column(metric: str = "sed_median", threshold: float | None = None) -> str:
    """The header of a count of fails: "fails (sed_median > 2 px)"."""
    return f"fails ({fails_label(metric, threshold)})"


def fails_label(metric: str, threshold: float | None = None) -> str:
    """What "fails" means for ``metric``: "sed_median > 2 px", "inlier_ratio < 0.5", "no value" (no threshold)."""
    rule = fail_rule(metric, threshold)
    if rule is None:
        return "no value"
    unit = f" {rule.unit}" if rule.unit else ""
    return f"{metric} {'<' if rule.higher_is_better else '>'} {rule.threshold:g}{unit}"
