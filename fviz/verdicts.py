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

import numpy as np

from fviz.evaluate import EVAL_THRESHOLD_PX, GT_NAME
from fviz.evidence import STATIC_FRACTION
from fviz.geometry import NSGD_RECALL_THRESHOLD
from fviz.stats import number


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
    from fviz.evaluate import metric_unit

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


# ---------------------------------------------------------------------------------------------- one pair's verdict
# What went wrong on a pair, in one line with the number behind it: the head of every pair view (inspect, eval
# --full, triage's banner) and inspect's output. Its words are triage's tags (fviz.triage), judged by the same rules.

PAIR_FAILED, TOO_FEW, INPUTS, NO_EVAL = "pair failed", "too few to judge", "inputs suspect", "no evaluation matches"
DEGENERATE, GT_SUSPECT = "degenerate", "ground truth suspect"
MATCHER, ESTIMATOR, FAILS, NO_GT, NO_FAILURE = "matcher", "estimator", "fails", "no ground truth", "no failure"
VERDICTS = (PAIR_FAILED, TOO_FEW, INPUTS, NO_EVAL, DEGENERATE, GT_SUSPECT, MATCHER, ESTIMATOR, FAILS, NO_GT,
            NO_FAILURE)  # the first that applies
DEGENERATE_FRACTION = STATIC_FRACTION  # degenerate: this share of the matches static (diagnose.STATIC_PX)
MATCHER_MIN_PRECISION = 0.5  # the matcher is to blame for a failing estimate when fewer than this share of the
MATCHER_MIN_CORRECT = 20  # matches lie within 2 px of F_gt, or fewer than this many within 1 px (match_precision)


@dataclass(frozen=True)
class Verdict:
    """A pair's verdict: ``kind`` (one of VERDICTS), ``text``, the evidence with its numbers, and ``detail``, which
    of a kind's causes ("swapped", "scale", "K" for INPUTS; "static", "planar", "rotation" for DEGENERATE)."""

    kind: str
    text: str
    detail: str = ""

    @property
    def line(self) -> str:
        return f"{self.kind}: {self.text}"

    def markdown(self) -> str:
        return f"**{self.kind}**: {self.text}"




def failure(row: dict) -> str:
    """Why an estimate (a result row: ``name``, ``error``, ``metrics``) fails its pair, "" when it passes every figure
    the pair gives: it failed (no F); its pose error is above POSE_FAIL_DEG, or no pose could be recovered from it
    although the pair has cameras and a ground-truth pose (no decomposition of its E puts the evaluation matches in
    front of both cameras); its epipole is more than POSE_FAIL_DEG off; its median SED is above 2 px or undefined.
    A pose left undefined for want of evaluation matches (``pose_undefined``) is not held against the estimate."""
    if row.get("error"):
        return f"gave no F: {str(row['error']).splitlines()[0][:80]}"
    m = row.get("metrics") or {}
    pose, sed, epipole = number(m.get("pose_err_deg")), number(m.get("sed_median")), number(m.get("epipole_err_deg"))
    why = []
    if math.isfinite(pose) and FAIL_RULES["pose_err_deg"].fails(pose):
        why.append(f"pose error {pose:.3g} deg")
    elif "pose_err_deg" in m and not math.isfinite(pose) and not m.get("pose_undefined"):
        why.append("no pose: no decomposition puts the points in front of both cameras"
                   + (f", epipole {epipole:.3g} deg off" if math.isfinite(epipole) else ""))
    elif math.isfinite(epipole) and FAIL_RULES["epipole_err_deg"].fails(epipole):
        why.append(f"epipole {epipole:.3g} deg off")
    if FAIL_RULES["sed_median"].fails(sed):
        why.append(f"median SED {sed:.3g} px" if math.isfinite(sed) else "no median SED")
    return ", ".join(why)


def blame(precision: dict, n_matches: int) -> tuple[str, str]:
    """Whose fault a failing estimate is, from the matches' precision (``match_precision``, before any estimator):
    (MATCHER or ESTIMATOR, the number that decides: "12% of the 300 matches lie within 2 px of F_gt")."""
    p1, p2 = number(precision.get("px_prec@1")), number(precision.get("px_prec@2"))
    correct = p1 * n_matches
    share = f"{p2:.0%} of the {n_matches} matches lie within 2 px of F_gt"
    if not p2 >= MATCHER_MIN_PRECISION:
        return MATCHER, share
    if not correct >= MATCHER_MIN_CORRECT:
        return MATCHER, f"{correct:.0f} of the {n_matches} matches lie within 1 px of F_gt"
    return ESTIMATOR, share


def blamed(who: str, kind: str, numbers: str) -> str:
    """``who`` (what fails) and whose fault it is: "8point fails (...) although 90% of ...: not the matcher"."""
    return f"{who} but only {numbers}: the matcher's fault" if kind == MATCHER else f"{who} although {numbers}: not the matcher"


def fail_phrase(failing: list[tuple[str, str]]) -> str:
    """"8point fails (pose error 75 deg)", "8point (...) and ransac (...) fail"."""
    if len(failing) == 1:
        return f"{failing[0][0]} fails ({failing[0][1]})"
    return ", ".join(f"{n} ({why})" for n, why in failing[:-1]) + f" and {failing[-1][0]} ({failing[-1][1]}) fail"


def pair_verdict(rec: dict, by: str | None = None) -> Verdict:
    """The verdict of one pair (a results.jsonl record: ``error``, ``result``, ``diagnostics``), the first of
    VERDICTS that applies, the cheaper explanations before the ground truth:

    the pair failed; its matches do not move (``degenerate``, static: any F fits them); it has fewer than
    MIN_EVIDENCE matches, or fewer evaluation matches and no robust consensus of
    that many (``too few to judge``: F has 7 degrees of freedom, and evidence needs spare matches; the failing
    estimates are still named); the user's inputs explain the matches
    better than the ground truth does (:func:`fviz.diagnose.input_mistake`: swapped or rescaled matches, a K for
    another image); none of the matches is an evaluation match; where an estimate fails, one homography explains
    nearly all of the matches (``degenerate``: planar or a pure rotation); the
    ground truth is suspect (:func:`fviz.diagnose.gt_suspect`); an estimate fails (:func:`failure`) and the matches'
    precision says whose fault (``matcher`` / ``estimator``; ``fails`` where the precision is unknown); no ground
    truth (how far the estimates agree); no failure. ``by``: judge that estimator alone (triage's ranked one);
    default every estimator but the baselines. A network's estimate (``deep``) is set beside the straight-ahead
    constant on the same points."""
    from fviz.diagnose import MIN_EVIDENCE, STATIC_PX, gt_suspect, input_mistake
    from fviz.estimators.registry import is_baseline

    res = rec.get("result")
    if rec.get("error") or not res:
        return Verdict(PAIR_FAILED, str(rec.get("error") or "no result").splitlines()[0][:160])
    diag, rows, n = rec.get("diagnostics") or {}, res["estimators"], res["n_matches"]
    ests = [e for e in rows if e["name"] != GT_NAME]
    judged = [e for e in ests if e["name"] == by] if by else [e for e in ests if not is_baseline(e["name"])] or ests
    has_gt = res.get("F_gt") is not None
    failing = [(e["name"], why) for e in judged if (why := failure(e) if has_gt or e.get("error") else "")]
    if few := _too_few(res, rows, MIN_EVIDENCE):
        measured = f"; {fail_phrase(failing)}" if failing else ""
        return Verdict(TOO_FEW, f"{few}, fewer than {MIN_EVIDENCE} (F's 7 degrees of freedom and 8 spare): no fit or "
                       f"residual of so few is evidence{measured}; try another matcher or more keypoints "
                       "(--max-keypoints)")
    if (static := _degenerate(diag, n, STATIC_PX, False)) is not None:
        return static
    if not has_gt:  # only an error fails an estimate (its residuals are over every match)
        v = _agreement_verdict(res, [e["name"] for e in judged if not e.get("error")])
        return Verdict(v.kind, v.text + "".join(f"; {name} {why}" for name, why in failing))
    if mistake := input_mistake(diag):
        return Verdict(INPUTS, mistake["text"], mistake["detail"])  # the metrics against F_gt mean nothing so
    suspect = gt_suspect(diag, rows)
    if res["n_eval"] == 0:
        why = f"ground truth suspect: {suspect['short']}" if suspect else "the matcher or the ground truth is wrong"
        return Verdict(NO_EVAL, f"0 of {n} matches within {res['eval_threshold_px']:g} px of F_gt's lines: no metric; {why}")
    if degenerate := _degenerate(diag, n, STATIC_PX, bool(failing)):
        return degenerate
    if suspect:
        return Verdict(GT_SUSPECT, f"{suspect['short']}: trust {suspect['reference']}'s F, not the metrics")
    fine = [e["name"] for e in judged if e["name"] not in dict(failing)]
    beside = _beside_constant(diag, rows)
    if failing:
        who = fail_phrase(failing)
        also = f"; {', '.join(fine)} fine" if fine else ""
        if not res.get("match_precision"):
            return Verdict(FAILS, f"{who}; whose fault is unknown (no pose: no match precision){also}{beside}")
        kind, numbers = blame(res["match_precision"], n)
        return Verdict(kind, blamed(who, kind, numbers) + also + beside)
    best = min(judged, key=lambda e: number(e["metrics"].get("sed_median")), default=None)
    sed = number(best["metrics"].get("sed_median")) if best else float("nan")
    return Verdict(NO_FAILURE, f"{', '.join(e['name'] for e in judged) or 'no estimator'} within median SED "
                   f"{FAIL_RULES['sed_median'].threshold:g} px, pose and epipole error {POSE_FAIL_DEG:g} deg"
                   + (f" (best: {best['name']}, median SED {sed:.3g} px)" if best else "") + beside)


def _too_few(res: dict, rows: list[dict], minimum: int) -> str:
    """"" or why a pair has too few matches to judge: fewer than ``minimum`` matches; or, with ground truth, fewer than
    ``minimum`` evaluation matches and no robust estimator with a consensus of ``minimum`` inliers (neither the ground
    truth nor any fit has spare matches to be evidence of anything)."""
    from fviz.diagnose import is_robust

    n = res["n_matches"]
    if n < minimum:
        return f"{n} matches"
    if res.get("F_gt") is None or res.get("n_eval", 0) >= minimum:
        return ""
    best = max((number(e["metrics"].get("n_inliers")) for e in rows if is_robust(e["name"]) and not e.get("error")),
               default=float("nan"))
    if not best >= minimum:
        inliers = f"{best:.0f} inliers" if math.isfinite(best) else "no robust estimator's inliers"
        return f"{res['n_eval']} of the {n} matches near F_gt and {inliers} at most"
    return ""


def _degenerate(diag: dict, n: int, static_px: float, failing: bool) -> Verdict | None:
    """A pair whose matches cannot determine F: they do not move (static), or, where an estimate fails, one
    homography explains DEGENERATE_H_FRACTION of them (a plane, or a pure rotation when the ground truth's
    rotation explains them too)."""
    from fviz.diagnose import DEGENERATE_H_FRACTION, ROTATION_FRACTION

    static = number(diag.get("static_fraction"))
    if static >= DEGENERATE_FRACTION:
        return Verdict(DEGENERATE, f"{static:.0%} of the {n} matches move < {static_px:g} px: any F through the points "
                       "fits them, residuals and inliers mean nothing", "static")
    h = number(diag.get("homography_fraction"))
    if not (failing and h >= DEGENERATE_H_FRACTION):
        return None
    rotation = number(diag.get("rotation_fraction")) >= ROTATION_FRACTION
    what = "a pure rotation" if rotation else "a plane (or a rotation)"
    return Verdict(DEGENERATE, f"one homography explains {h:.0%} of the {n} matches, {what}: they do not determine F, "
                   "so an estimate may fail without the matcher, the estimator or the ground truth being wrong",
                   "rotation" if rotation else "planar")


def _beside_constant(diag: dict, rows: list[dict]) -> str:
    """"; deep 3.1 px vs ahead 2.9 px sed_median: no better than the constant" for a network's estimate, set beside
    straight-ahead motion on the same evaluation matches (:func:`fviz.estimators.baselines.deep_versus_ahead`;
    ``ahead``'s row, else its median SED that :func:`fviz.diagnose.diagnose` measures on every pair with cameras);
    "" without a network's estimate or cameras."""
    from fviz.estimators.baselines import deep_versus_ahead

    ahead = number(diag.get("ahead_sed_median"))
    if not any(r["name"] == "ahead" for r in rows) and math.isfinite(ahead):
        rows = [*rows, {"name": "ahead", "error": None, "metrics": {"sed_median": ahead}}]
    judged = deep_versus_ahead(rows)
    return f"; {judged['text']}" if judged else ""


def _agreement_verdict(res: dict, names: list[str]) -> Verdict:
    """Without ground truth: the two estimates closest to each other (NSGD) and whether they agree."""
    agreement = res.get("agreement") or {}
    order = list(agreement.get("names", []))
    m = np.array(agreement.get("matrix") or np.zeros((0, 0)), float)
    idx = [order.index(n) for n in names if n in order]
    if len(idx) < 2:
        return Verdict(NO_GT, "fewer than two estimates to compare with each other")
    rule = FAIL_RULES["agreement_nsgd"]
    d, i, j = min((m[i, j], i, j) for k, i in enumerate(idx) for j in idx[k + 1:])
    others = [(max(m[k, i], m[k, j]), order[k]) for k in idx if k not in (i, j)]
    far = f"; farthest from them {max(others)[1]} (NSGD {max(others)[0]:.2g})" if others else ""
    return Verdict(NO_GT, f"{order[i]} and {order[j]} {'agree' if not rule.fails(d) else 'disagree'} (NSGD {d:.2g} "
                   f"{'<' if not rule.fails(d) else '>'} {rule.threshold:g}){far}; the metrics compare the estimates only")


def verdict_of(pair, result, by: str | None = None) -> Verdict:
    """:func:`pair_verdict` of an evaluated pair (:class:`fviz.evaluate.PairResult`), its evidence computed here."""
    from fviz.diagnose import diagnosed

    ok = result.matches is not None and result.eval_mask is not None
    return pair_verdict({"error": None, "result": result.to_dict(),
                         "diagnostics": diagnosed(pair, result) if ok else None}, by)
