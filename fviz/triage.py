"""Failure-case triage: findings per estimator over a run, then its pairs ranked worst first with the
likely cause of each failure.

Per-pair evidence (:func:`fviz.diagnose.diagnose`) is computed by ``eval`` while the matches are at hand
and stored in results.jsonl, so triage mostly reads records; the two-view checks (``colmap-*``,
``focal-implausible``: :func:`fviz.diagnose.two_view_evidence`) it computes itself for the pairs it lists,
which it evaluates again for triage.rrd anyway.

Estimator findings (over the whole run, printed above the pairs):

- ``ignores-input``: over IGNORES_MIN_PAIRS or more pairs, the estimator's epipole (viewing ray K_a^-1 e_a) or
  recovered rotation cannot be told from one that ignores the images: the slope of its pair-to-pair offsets on
  the ground truth's (:func:`tracking_slope`; 1 follows, 0 ignores, whatever its own jitter) has an
  IGNORES_CONFIDENCE interval (a paired bootstrap over the pairs) reaching below IGNORES_FRACTION. A paired
  judgement: a spread of 11 % of the truth's made of jitter is no pass, a faithful but damped one is; a quantity the ground truth
  itself varies by less than MIN_GT_SPREAD_DEG is not judged (a steady turn, rectified stereo). That part
  of its output barely depends on the images: a constant, or a network that collapsed to one. Either
  quantity suffices: on sequence 00 the bundled network's epipole spreads 0.049 deg against the truth's
  0.57 deg while its rotation jitters more than the truth's (0.17 vs 0.14 deg) without following it;
- ``worse-than-baseline``: its median over pairs of ``sed_median`` (failures count as infinite) is above
  that of ``ahead`` (straight-ahead motion from the cameras alone), measured on every pair by eval.

Pair tags (thresholds are the constants below and in :mod:`fviz.diagnose`):

- ``error``: a pair error (not evaluated: missing image, fewer than MIN_MATCHES matches) or an estimator raised;
- ``few-matches``: fewer than FEW_MATCHES matches;
- ``low-inliers``: the ranked estimator's inlier ratio is below LOW_INLIER_RATIO;
- ``inputs-suspect``: the user's inputs explain the matches' misfit more cheaply than a wrong ground truth
  (:func:`fviz.diagnose.input_mistake`: matches that F_gt explains INPUT_RATIO times better with a and b swapped or at
  another scale, a K whose principal point is far from its image's centre); judged before ``gt-suspect``, which it
  silences;
- ``gt-suspect``: a property of the pair, whatever estimator ranks it (:func:`fviz.diagnose.gt_suspect`, the
  same verdict ``inspect`` prints): the ground truth explains the matches worse than the estimates do. Of the
  estimators fitting the matches with a consensus (inlier ratio >= GT_SUSPECT_INLIER_RATIO), the largest one's
  inliers sit farther from F_gt's lines than from its own, by more than GT_SUSPECT_RATIO times and a margin of
  GT_SUSPECT_MARGIN_PX or half the ground truth's stated accuracy (``gt_accuracy_px``: 3 px for KITTI's odometry
  poses, 0.5 px for its stereo calibration); or, on a well-conditioned pair (not small-baseline, not planar) whose
  F_gt puts the epipoles near the images (forward motion), every tight fit (median SED < GT_SUSPECT_FIT_PX) puts its
  epipole more than GT_SUSPECT_DIRECTION_DEG or its rotation more than GT_SUSPECT_ROTATION_DEG away from the ground
  truth's and fits its own inliers better than F_gt does (by GT_SUSPECT_DIRECTION_MARGIN_PX or a tenth of the
  accuracy) -> suspected ground-truth (pose or calibration) error rather than an estimation failure. The second
  test is the one that holds on forward motion, where a pose 13 deg off in translation direction still
  leaves most matches within 1-2 px of its epipolar lines (sequence 00 with its trajectory turned by 13
  deg: the robust estimators' epipoles are then 9-18 deg off, against 1-5 deg with the official poses).
  An epipole far from the images or at infinity (sideways motion, rectified stereo) is poorly determined: an
  estimate 6-20 deg off there, fitting the matches no better than the ground truth, accuses nothing (Strecha's
  fountain, KITTI's colour stereo). The reason names the estimator to trust instead;
- ``planar``: one homography (RANSAC, HOMOGRAPHY_PX) explains at least PLANAR_FRACTION of the ranked
  estimator's inliers: a near-degenerate (planar) configuration for F;
- ``small-baseline``: the ground-truth translation is below SMALL_BASELINE_M, or the infinite
  homography K_b R K_a^-1 (pure rotation) explains at least ROTATION_FRACTION of the matches within
  ROTATION_PX: the epipolar geometry is barely observable;
- ``degenerate``: at least DEGENERATE_FRACTION of the matches move less than STATIC_PX (identical or
  frozen images): every F whose lines pass through the points fits them, so near-zero residuals and
  100 % inliers say nothing.

- ``matcher`` / ``estimator``: the ranked estimator fails the pair (an error, ``pose_err_deg`` >
  FAIL_POSE_DEG or ``sed_median`` > FAIL_SED_PX) and the matches were (``matcher``) or were not (``estimator``)
  to blame: fewer than MATCHER_MIN_PRECISION of them within 2 px of F_gt, or fewer than MATCHER_MIN_CORRECT
  within 1 px (``match_precision``, computed before any estimator); not on a ``gt-suspect`` pair, where both
  are measured against a doubtful ground truth;
- ``colmap-planar``, ``colmap-panoramic``, ``colmap-planar-or-panoramic``, ``colmap-watermark``,
  ``colmap-degenerate``: COLMAP's two-view configuration of the matches (pycolmap, with the pair's cameras);
- ``focal-implausible``: the ranked estimator's F gives imaginary focal lengths (Bougnoux, PoseLib) or ones
  more than FOCAL_OFF times off K's, on a pair whose matches determine the focals (``focal_observable``
  in :mod:`fviz.diagnose`; never on rectified stereo or forward motion, where no F does).
  These two are judged on the listed pairs (``--top``) only: their checks cost more than the rest of a
  pair's evaluation outside feature detection, so eval does not run them on every pair.

There is no tag for an epipole inside the image: on forward motion it holds for every pair.
"""

from __future__ import annotations

import math
import shlex
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fviz.atomic import write_text
from fviz.diagnose import (
    GT_SUSPECT_DIRECTION_DEG,
    GT_SUSPECT_DIRECTION_MARGIN_PX,
    GT_SUSPECT_EPIPOLE_NEAR,
    GT_SUSPECT_FIT_PX,
    GT_SUSPECT_INLIER_RATIO,
    GT_SUSPECT_MARGIN_PX,
    GT_SUSPECT_RATIO,
    GT_SUSPECT_ROTATION_DEG,
    HOMOGRAPHY_PX,
    MIN_EVIDENCE,
    PLANAR_FRACTION,
    ROTATION_FRACTION,
    ROTATION_PX,
    SMALL_BASELINE_M,
    STATIC_PX,
    gt_suspect,
    input_mistake,
)
from fviz.errors import FvizError
from fviz.estimators.registry import AHEAD, is_oracle, is_run_baseline
from fviz.evaluate import EVAL_THRESHOLD_PX, metric_unit
from fviz.findings import IGNORES_FRACTION, IGNORES_MIN_PAIRS, MIN_GT_SPREAD_DEG, Finding, estimator_findings  # noqa: F401 (re-exported)
from fviz.record import layout as L
from fviz.stats import fmt, number
from fviz.verdicts import (  # noqa: F401 (re-exported)
    DEGENERATE_FRACTION,
    ERROR,
    FAIL_RULES,
    HIGHER_IS_BETTER,
    LOW_INLIER_RATIO,
    MATCHER_MIN_CORRECT,
    MATCHER_MIN_PRECISION,
    blame,
    blamed,
    fail_phrase,
    failure,
    pair_verdict,
)

FEW_MATCHES = 50
FAIL_POSE_DEG = FAIL_RULES["pose_err_deg"].threshold  # one vocabulary of "fails" (fviz.verdicts)
FAIL_SED_PX = FAIL_RULES["sed_median"].threshold
FOCAL_OFF = 2.0
COLMAP_TAGGED = ("planar", "panoramic", "planar_or_panoramic", "watermark", "degenerate")

TAGS = ("error", "few-matches", "low-inliers", "inputs-suspect", "gt-suspect", "planar", "small-baseline", "degenerate", "matcher",
        "estimator", *(f"colmap-{c.replace('_', '-')}" for c in COLMAP_TAGGED), "focal-implausible")
NOT_RANKING = {"f_dist": "unconditioned ||F - F_gt|| of pixel-coordinate F misranks estimators; "
                         "rank by sed_median, pose_err_deg or nsgd"}
TRIAGE_FILE = "triage.md"
TRIAGE_RRD = "triage.rrd"
RANK_TIMELINE = L.RANK_TIMELINE
TAGS_ENTITY = L.TRIAGE_TAGS


# ------------------------------------------------------------------------------ tags and ranking


def tag_pair(rec: dict[str, Any], by: str) -> list[tuple[str, str]]:
    """(tag, why) of one record of results.jsonl, judged on estimator ``by``."""
    out: list[tuple[str, str]] = []
    errors = [rec["error"]] if rec["error"] else []
    res = rec.get("result") or {}
    errors += [f"{e['name']}: {e['error']}" for e in res.get("estimators", []) if e["error"] and not rec["error"]]
    if errors:
        out.append(("error", "; ".join(errors)))
    diag = rec.get("diagnostics")
    if not diag:
        return out
    n = diag["n_matches"]
    if n < FEW_MATCHES:
        out.append(("few-matches", f"{n} matches < {FEW_MATCHES}"))
    metrics = next((e["metrics"] for e in res["estimators"] if e["name"] == by), {})
    ratio, ev = number(metrics.get("inlier_ratio")), diag["estimators"].get(by, {})
    if ratio < LOW_INLIER_RATIO:
        out.append(("low-inliers", f"{by} inlier ratio {ratio:.2f} < {LOW_INLIER_RATIO}"))
    mistake = input_mistake(diag)
    if mistake:
        out.append(("inputs-suspect", f"{mistake['detail']}: {mistake['text']}"))
    suspect = gt_suspect(diag, res.get("estimators", []))
    if suspect:
        out.append(("gt-suspect", f"{suspect['why']}; reference: {suspect['reference']}"))
    hom = number(ev.get("homography_fraction"))
    if hom >= PLANAR_FRACTION:
        out.append(("planar", f"a homography explains {hom:.0%} of {by}'s inliers (>= {PLANAR_FRACTION:.0%})"))
    base, rot = diag["baseline_m"], number(diag["rotation_fraction"])
    if base < SMALL_BASELINE_M or rot >= ROTATION_FRACTION:
        out.append(("small-baseline", f"|t| = {base:.3f} m, K_b R K_a^-1 explains {rot:.0%} of the matches"))
    static = number(diag.get("static_fraction"))
    if static >= DEGENERATE_FRACTION:
        out.append(("degenerate", f"{static:.0%} of the matches move < {STATIC_PX:g} px (identical images?): any F "
                    "through the points fits, residuals and inlier counts mean nothing"))
    # judged against doubtful labels or inputs, or on too few matches to be evidence, neither is to blame
    doubtful = any(t in ("gt-suspect", "inputs-suspect") for t, _ in out) or n < MIN_EVIDENCE
    return out + ([] if doubtful else blame_tags(rec, by)) + two_view_tags(rec, by)


def blame_tags(rec: dict[str, Any], by: str) -> list[tuple[str, str]]:
    """``matcher`` or ``estimator`` for a pair ``by`` fails on (see the module doc; the rule: fviz.verdicts.blame)."""
    res = rec.get("result") or {}
    prec, e = res.get("match_precision") or {}, next((e for e in res.get("estimators", []) if e["name"] == by), None)
    why = failure(e) if prec and e is not None else ""
    if not why:
        return []
    kind, numbers = blame(prec, res.get("n_matches", 0))
    return [(kind, blamed(fail_phrase([(by, why)]), kind, numbers))]


def two_view_tags(rec: dict[str, Any], by: str) -> list[tuple[str, str]]:
    """COLMAP's configuration label and ``focal-implausible`` (see the module doc)."""
    diag, out = rec.get("diagnostics") or {}, []
    label = diag.get("two_view", "")
    if label in COLMAP_TAGGED:
        out.append((f"colmap-{label.replace('_', '-')}", f"COLMAP's two-view geometry labels the matches {label.upper()}"))
    f = [number(v) for v in (diag.get("estimators", {}).get(by, {}).get("focals") or [])]
    K = [np.array((rec.get("result") or {}).get("pair", {}).get(k, np.full((3, 3), np.nan))) for k in ("K_a", "K_b")]
    if diag.get("focal_observable") and len(f) == 2:
        ratio = [fi / k[0, 0] for fi, k in zip(f, K)]
        if not all(1 / FOCAL_OFF <= r <= FOCAL_OFF for r in ratio):  # NaN: imaginary
            out.append(("focal-implausible", f"{by}'s F gives focals {f[0]:.0f} / {f[1]:.0f} px (Bougnoux; nan: "
                        f"imaginary) against K's {K[0][0, 0]:.0f} / {K[1][0, 0]:.0f} px"))
    return out


# ------------------------------------------------------------------------------ estimator findings


@dataclass
class Ranked:
    """One pair of the ranking (rank 0 = worst)."""

    rank: int
    index: int
    key: str
    value: float
    failed: bool
    tags: list[tuple[str, str]] = field(default_factory=list)
    ref: dict[str, Any] = field(default_factory=dict)
    pose_err: float = float("nan")  # pose_err_deg of the ranked estimator


def metric_value(rec: dict[str, Any], by: str, metric: str) -> float:
    """The metric of estimator ``by`` on a record; NaN when the pair or the estimator failed."""
    if rec["error"] or not rec.get("result"):
        return float("nan")
    e = next((e for e in rec["result"]["estimators"] if e["name"] == by), None)
    return float("nan") if e is None or e["error"] else number(e["metrics"].get(metric))


def rank_pairs(records, by: str, metric: str) -> list[Ranked]:
    """Every pair, worst first: failures (NaN) first, then by the metric (largest first, or smallest for
    metrics where higher is better); ties by pair index."""
    sign = -1.0 if metric in HIGHER_IS_BETTER else 1.0
    items = []
    for rec in records:
        v = metric_value(rec, by, metric)
        items.append(Ranked(0, rec["index"], rec["key"], v, not math.isfinite(v), tag_pair(rec, by), rec["ref"],
                            metric_value(rec, by, "pose_err_deg")))
    items.sort(key=lambda r: (not r.failed, -sign * r.value if not r.failed else 0.0, r.index))
    for i, r in enumerate(items):
        r.rank = i
    return items


def check_choice(config, records_sample: dict[str, Any] | None, by: str, metric: str) -> None:
    """One-line errors for a --by that is not one of the run's estimators or an unknown --metric."""
    names = config.series_names()
    if by not in names:
        raise FvizError(f"--by {by!r}: not an estimator of this run (choose one of {', '.join(names)})")
    if metric in NOT_RANKING:
        raise FvizError(f"--metric {metric}: not a ranking metric ({NOT_RANKING[metric]})")
    if records_sample is not None:
        keys = [k for k in next((e["metrics"] for e in records_sample["result"]["estimators"] if e["metrics"]), ())
                if k not in NOT_RANKING]
        if keys and metric not in keys:
            raise FvizError(f"--metric {metric!r}: unknown (choose one of {', '.join(keys)})")


# ------------------------------------------------------------------------------ reports


def inspect_command(config, source, ref: dict[str, Any]) -> str:
    """The ``fviz inspect pair`` command that reopens a pair with the run's options."""
    from fviz.data.pair import PairId
    from fviz.estimators.options import EstimatorOptions
    pid = PairId(**{k: v for k, v in ref.items() if k != "name"})
    args = ["fviz", "inspect", "pair", *source.inspect_args(pid)]
    for name in config.options.names:
        if not is_run_baseline(name):
            args += ["-e", name]
    o, default = config.options, EstimatorOptions(names=())
    flags = {"features": "--features", "max_keypoints": "--max-keypoints", "ratio": "--ratio", "threshold": "--threshold",
             "confidence": "--confidence", "max_iters": "--max-iters", "seed": "--seed"}
    for attr, flag in flags.items():
        if getattr(o, attr) != getattr(default, attr) and not (attr == "seed" and config.selection.synthetic):
            args += [flag, str(getattr(o, attr))]
    if not o.mutual:
        args.append("--no-mutual")
    if config.norm != "fbn":
        args += ["--norm", config.norm]
    if config.eval_threshold != EVAL_THRESHOLD_PX:
        args += ["--eval-threshold", str(config.eval_threshold)]
    return shlex.join(args)


def open_command(out_dir: Path, key: str, versus: Path | None = None) -> str:
    """The ``fviz open RUN --pair NAME [--versus RUN_B] --web`` command that shows a pair of the run from the run's own
    folder (its matches and settings; beside the same pair of run ``versus``), clickable and editable."""
    return shlex.join(["fviz", "open", str(out_dir), "--pair", key, *(["--versus", str(versus)] if versus else []), "--web"])


def _tag_text(r: Ranked) -> str:
    return ", ".join(t for t, _ in r.tags) or "-"


def _label(name: str) -> str:
    return f"{name} (oracle: has seen the labels)" if is_oracle(name) else name


def findings_markdown(findings: list[Finding]) -> list[str]:
    lines = [
        "## Estimators over the run",
        "",
        f"Spreads: median angle of the epipole ray K_a^-1 e_a and of the recovered rotation to their median over the run; "
        f"`ignores-input` when either is below {IGNORES_FRACTION:.0%} of the ground truth's over the same pairs "
        f"(at least {IGNORES_MIN_PAIRS} pairs); `worse-than-baseline` when the median SED is above `{AHEAD}`'s "
        "(F = K_b^-T [z]x K_a^-1, from the cameras alone). Failures count as infinite in the medians.",
        "",
        "| estimator | median SED px | median pose err deg | epipole spread deg (GT) | rotation spread deg (GT) | findings |",
        "|---|---|---|---|---|---|",
    ]
    for f in findings:
        lines.append(f"| {_label(f.name)} | {fmt(f.sed_median, 4, ERROR)} | {fmt(f.pose_err_median, 4, ERROR)} | "
                     f"{f.epipole_spread:.3g} ({f.gt_epipole_spread:.3g}) | {f.rotation_spread:.3g} ({f.gt_rotation_spread:.3g}) | "
                     f"{', '.join(t for t, _ in f.flags) or '-'} |")
    for f in findings:
        lines += [f"- **{f.name}: {t}**: {why}" for t, why in f.flags]
    return lines


def triage_markdown(config, ranked: list[Ranked], top: int, by: str, metric: str, source,
                    findings: list[Finding] = (), by_reason: str = "", out_dir: Path | None = None) -> str:
    counts = {t: sum(any(x == t for x, _ in r.tags) for r in ranked) for t in TAGS}
    worst = "smallest" if metric in HIGHER_IS_BETTER else "largest"
    lines = ["# fviz triage", "", f"{config.selection.describe()}: {len(ranked)} pairs.", ""]
    if findings:
        lines += findings_markdown(list(findings)) + [""]
    lines += [
        "## Pairs",
        "",
        f"Ranked by `{metric}` of `{by}`{f' ({by_reason})' if by_reason else ''}, worst first ({worst} value; pairs "
        f"where `{by}` has no value (an {ERROR}) come first); `--by NAME` ranks by another estimator.",
        "",
        "Tags over all pairs: " + ", ".join(f"`{t}` {counts[t]}" for t in TAGS) + ".",
        f"Thresholds: few-matches < {FEW_MATCHES}; low-inliers ratio < {LOW_INLIER_RATIO}; inputs-suspect: the "
        "matches fit F_gt swapped or rescaled, or K's principal point lies far from its image's centre (judged before "
        "gt-suspect); gt-suspect (of the pair, whatever `--by`; never from a fit of fewer than "
        f"{MIN_EVIDENCE} inliers, nor from 7- or 8-point): F_gt explains the matches worse than a robust estimate does out "
        f"of sample: the largest consensus (ratio >= {GT_SUSPECT_INLIER_RATIO}) has its inliers' median distance to F_gt's "
        f"lines > {GT_SUSPECT_RATIO:g}x their held-out one and more than max({GT_SUSPECT_MARGIN_PX:g} px, half the ground "
        "truth's stated accuracy) above it, or, on a pair neither small-baseline nor planar whose F_gt epipoles lie within "
        f"{GT_SUSPECT_EPIPOLE_NEAR:g} image diagonal of the images, two or more tight robust fits (held-out median SED < "
        f"{GT_SUSPECT_FIT_PX:g} px) all have their epipole > {GT_SUSPECT_DIRECTION_DEG:g} deg or rotation > "
        f"{GT_SUSPECT_ROTATION_DEG:g} deg off and fit their inliers better than F_gt by max("
        f"{GT_SUSPECT_DIRECTION_MARGIN_PX:g} px, a tenth of the accuracy); not where F_gt fits a tight set of the matches "
        f"itself (repeated texture); planar: a homography ({HOMOGRAPHY_PX:g} px) explains >= {PLANAR_FRACTION:.0%} "
        f"of the inliers; small-baseline: |t| < {SMALL_BASELINE_M} m or K_b R K_a^-1 explains >= {ROTATION_FRACTION:.0%} "
        f"of the matches within {ROTATION_PX:g} px; degenerate: >= {DEGENERATE_FRACTION:.0%} of the matches move < "
        f"{STATIC_PX:g} px.",
        f"matcher / estimator (not below {MIN_EVIDENCE} matches): `{by}` fails (an {ERROR}, pose error > "
        f"{FAIL_POSE_DEG:g} deg or no pose, epipole error > {FAIL_POSE_DEG:g} deg, median SED > {FAIL_SED_PX:g} px) and "
        f"fewer than {MATCHER_MIN_PRECISION:.0%} of the matches lie within 2 px of F_gt or fewer than {MATCHER_MIN_CORRECT} "
        f"within 1 px (matcher), or not (estimator); colmap-*: COLMAP's two-view configuration of the matches; "
        f"focal-implausible: Bougnoux focals of `{by}`'s F imaginary or more than {FOCAL_OFF:g}x off K's, where the "
        "matches determine them (these two judged on the listed pairs only).",
        "",
        f"| rank | pair | {metric} | pose_err_deg | tags |",
        "|---|---|---|---|---|",
    ]
    shown = ranked[:top]
    for r in shown:
        lines.append(f"| {r.rank} | `{r.key}` | {fmt(r.value, 4, ERROR)} | {fmt(r.pose_err, 4, ERROR)} | {_tag_text(r)} |")
    for r in shown:
        lines += ["", f"### rank {r.rank}: `{r.key}`", "", f"{metric} of {by}: {fmt(r.value, 4, ERROR)}"]
        lines += [f"- **{t}**: {why}" for t, why in r.tags]
        lines += ["", "```", inspect_command(config, source, r.ref), "```"]
        lines += ["", "From the run's folder (its matches and settings; click, edit):", "", "```",
                  open_command(out_dir, r.key), "```"] if out_dir is not None else []
    if any(is_run_baseline(n) for n in config.options.names):
        lines += ["", "The run-level baselines (`oracle-mean`, `mean:...`) are not inspect estimators: the commands "
                  "above leave them out."]
    return "\n".join(lines) + "\n"


def rank_banner(r: Ranked, by: str, metric: str, rec: dict[str, Any]) -> str:
    """The head of a rank in triage.rrd: the pair's verdict judged on ``by`` (its record ``rec``: fviz.verdicts), one
    line first, so that the banner's height never hides it; then "rank 0: sed_median of 8point 3.34 px" and the tags."""
    value = ERROR if r.failed else f"{r.value:.3g}{(' ' + metric_unit(metric)) if metric_unit(metric) else ''}"
    return "\n".join([pair_verdict(rec, by).markdown(), "", f"**rank {r.rank}: {metric} of {by} {value}** (`{r.key}`, pair "
                      f"#{r.index}; ArrowRight: next worse-ranked pair)", ""] + [f"- **{t}**: {why}" for t, why in r.tags])


def write_triage_recording(path: Path, config, out_dir: Path, shown: list[Ranked], records: dict[int, dict],
                           by: str = "", metric: str = "sed_median") -> Path:
    """triage.rrd: the ``rank`` timeline steps through the worst pairs first, each with inspect's full
    payload (the pair is evaluated again: estimators are seeded, so the values are the run's; its two-view
    tags are added to ``shown`` then, see :func:`add_two_view`); it opens on ``rank`` and its series are
    plotted per rank, as points (the motion tracks, which follow consecutive pairs, are eval.rrd's)."""
    import rerun as rr

    from fviz.data.pair import PairId
    from fviz.diagnose import gt_suspect_note
    from fviz.record.pair_recording import log_pair
    from fviz.record.run_plots import log_static, series_ranges_of
    from fviz.record.writer import RecordingWriter
    from fviz.run import PairEvaluator, log_summary_pair, result_from_record

    evaluator = PairEvaluator(config, out_dir)
    size = next(((tuple(rec["result"]["pair"]["size_a"]), tuple(rec["result"]["pair"]["size_b"]))
                 for rec in records.values() if rec.get("result")), ((1242, 375), (1242, 375)))
    names = config.series_names()
    ranges = series_ranges_of(result_from_record(records[r.index], config) for r in shown)
    with RecordingWriter(path, "fviz-triage", L.blueprint(names, size, single_pair=False, head=True, ranges=ranges)) as w:
        log_static(w.rec, names, series=True, points=True, motion=False)  # over the ranks: neighbours are unrelated pairs
        for r in shown:
            rec = records[r.index]
            w.rec.set_time(L.RANK_TIMELINE, sequence=r.rank)
            try:
                pair, result = evaluator.evaluate(PairId(**{k: v for k, v in r.ref.items() if k != "name"}))
                add_two_view(r, rec, pair, result, by)
                if (note := gt_suspect_note(pair, result)) is not None:
                    result.notes.insert(0, note)
                log_pair(w.rec, r.index, pair, result, single_pair=False, clear_reference=True, motion=False, by=by)
            except Exception:  # the pair failed in eval too: its record says why
                log_summary_pair(w.rec, r.index, rec, result_from_record(rec, config), motion=False)
                w.rec.log(L.REFERENCE, rr.LineStrips2D([]))  # no reference lines left from the rank before
            w.rec.log(TAGS_ENTITY, rr.TextDocument(rank_banner(r, by, metric, rec), media_type="text/markdown"))
            w.pair_done()
    return path


@dataclass
class TriageOutcome:
    ranked: list[Ranked]
    markdown: Path
    recording: Path
    eval: Any = None
    by: str = ""
    findings: list[Finding] = field(default_factory=list)


def reuse_run(config, out_dir: Path):
    """``config`` widened to the run already in ``out_dir`` when its options agree: its estimators stay
    (those asked for that it lacks are added), its baselines' F are kept, so only what is missing is computed."""
    from fviz.run import read_config
    from fviz.run.config import RESULTS_FILE

    existing = read_config(out_dir)
    if existing is None or not (Path(out_dir) / RESULTS_FILE).is_file() or existing.comparable() != config.comparable():
        return config  # fresh, or run_eval says which options differ
    names = existing.options.names + tuple(n for n in config.options.names if n not in existing.options.names)
    return replace(config, options=replace(config.options, names=names), baseline_F=existing.baseline_F,
                   full=existing.full or config.full)


def run_triage(config, out_dir: str | Path, by: str | None = None, metric: str = "sed_median", top: int = 20,
               workers: int | None = None, progress: bool = True) -> TriageOutcome:
    """Evaluate what ``out_dir`` lacks (eval with resume semantics), rank, tag and write the reports.
    ``by`` defaults to the first estimator of ``config`` (the first one the user named)."""
    from fviz.estimators.registry import display_name
    from fviz.run import ResultStore, read_config, run_eval

    if top < 1:
        raise FvizError(f"--top {top}: must be >= 1")
    by_reason = "" if by else "the first estimator named; choose another with --by"
    by = by or display_name(config.options.names[0])
    config = reuse_run(config, Path(out_dir))
    check_choice(config, None, by, metric)
    outcome = run_eval(config, out_dir, workers, resume=True, progress=progress)
    out_dir = Path(out_dir)
    if outcome.interrupted:
        return TriageOutcome([], None, None, outcome, by)
    config = read_config(out_dir)
    store = ResultStore(out_dir)
    check_choice(config, next((r for r in store.records() if r.get("result") and not r["error"]), None), by, metric)
    ranked = rank_pairs(store.records(), by, metric)
    findings = estimator_findings(store.records(), config.estimator_names())
    shown = ranked[:top]
    wanted = {r.index for r in shown}
    records = {rec["index"]: rec for rec in store.records() if rec["index"] in wanted}
    source = config.selection.source()
    rrd = write_triage_recording(out_dir / TRIAGE_RRD, config, out_dir, shown, records, by, metric)  # tags the shown
    md = write_text(out_dir / TRIAGE_FILE, triage_markdown(config, ranked, top, by, metric, source, findings, by_reason,
                                                                 out_dir))
    return TriageOutcome(ranked, md, rrd, outcome, by, findings)


def add_two_view(r: Ranked, rec: dict[str, Any], pair, result, by: str) -> None:
    """Complete a listed pair's record with the two-view evidence eval leaves out (on the pair evaluated again:
    the same matches, estimators seeded) and tag it again (``colmap-*``, ``focal-implausible``)."""
    from fviz.diagnose import has_two_view, two_view_evidence, with_two_view

    diag = rec.get("diagnostics")
    if not diag or has_two_view(diag) or result.matches is None or result.eval_mask is None:
        return
    rec["diagnostics"] = with_two_view(diag, two_view_evidence(pair, result))
    r.tags = tag_pair(rec, by)
