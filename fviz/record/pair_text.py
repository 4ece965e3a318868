"""One pair's text: the summary's Markdown (the pair, its metrics table, hints, the F's), the estimators' captions
and epipole names below and on the images, the suspect ground truth's notice, and the text entities of a pair
(info, summary, metrics table, errors)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fviz.diagnose import GT_SUSPECT_NOTE
from fviz.evaluate import PairResult, agreement_text
from fviz.geometry import NSGD_RECALL_THRESHOLD
from fviz.record import layout as L
from fviz.record.placement import below_images
from fviz.record.marks import names_of, place_tags, rgb
from fviz.stats import fmt


SUMMARY_COLUMNS = (("sed_median", "SED px"), ("rot_err_deg", "rot °"), ("trans_err_deg", "trans °"),
                   ("nsgd", "NSGD"), ("inlier_ratio", "inliers"), ("agreement_nsgd", "NSGD to closest"))

_GROUND_TRUTH = {"pose": "the relative pose", "F": "a given F", "correspondences": "F fitted to the ground-truth correspondences"}


def _pair_sentence(result: PairResult) -> str:
    """What the pair is and what its metrics are computed on (KITTI frames and cameras, or a user's images)."""
    p = result.pair
    if "image_a" not in p:
        return (f"{p['kind']} pair, frame {p['frame_a']} cam {p['cam_a']} → frame {p['frame_b']} cam {p['cam_b']}; "
                f"ground truth good to ~{fmt(p['gt_accuracy_px'], 2)} px. {result.n_matches} matches, {result.n_eval} within "
                f"{result.eval_threshold_px:g} px of the GT lines (the evaluation matches).")
    head = f"`{p['image_a']}` → `{p['image_b']}` ({p['source']}); "
    gt = p.get("ground_truth", "none")
    if gt == "none":
        return head + (f"**no ground truth**: the estimators are compared with each other. {result.n_matches} matches; "
                       "SED and inliers are over all of them, *NSGD to closest* is the NSGD of an F to the closest "
                       "other estimator's (every two: table below). No GT-based metric is computed.")
    if result.eval_points == "gt-matches":
        where = f"{result.n_eval} ground-truth correspondences (the evaluation matches)"
    else:
        where = f"{result.n_eval} within {result.eval_threshold_px:g} px of the GT lines (the evaluation matches)"
    accuracy = "" if p.get("gt_accuracy_px") is None else f", good to ~{fmt(p['gt_accuracy_px'], 2)} px"
    return head + f"ground truth: {_GROUND_TRUTH.get(gt, gt)}{accuracy}. {result.n_matches} matches, {where}."


def precision_lines(prec: dict[str, float]) -> list[str]:
    """The match precision of a pair (fviz.geometry.precision) as one line, or none without it."""
    if not prec:
        return []
    pct = lambda k: "n/a" if not np.isfinite(prec.get(k, np.nan)) else f"{prec[k]:.0%}"  # noqa: E731
    px = [k for k in prec if k.startswith("px_prec@")]
    epi = [k for k in prec if k.startswith("epi_prec@")]
    return ["", "Match precision, before any estimator: " + ", ".join(f"{pct(k)} within {k.partition('@')[2]} px" for k in px)
            + " of F_gt; glue-factory's epi_prec@" + "/".join(k.partition("@")[2] for k in epi) + ": "
            + " / ".join(pct(k) for k in epi) + "."]


def pair_markdown(result: PairResult, probe_steps: int = 0) -> str:
    """The summary panel: the pair, a compact table (every metric is in the JSON), hints, F matrices last."""
    p = result.pair
    columns = [c for c in SUMMARY_COLUMNS if any(c[0] in r.metrics for r in result.estimators)] or list(SUMMARY_COLUMNS[:1])
    suspect = [n for n in result.notes if n.startswith(GT_SUSPECT_NOTE)]
    # reader.SUSPECT_BANNER
    lines = [f"**⚠ ground truth suspect**: {n.removeprefix(GT_SUSPECT_NOTE)}" for n in suspect] + [""] * bool(suspect)
    # the table first, so that it shows without scrolling (1600x1000); what it is computed on below it
    lines += [
        f"**{p['name']}**",
        "",
        "| F | " + " | ".join(t for _, t in columns) + " | time s |",
        "|---|" + "--:|" * (len(columns) + 1),
    ]
    for r in result.estimators:
        if r.error:
            lines.append(f"| {r.name} | failed |" + " |" * len(columns))
        else:
            lines.append(f"| {r.name} | " + " | ".join(fmt(r.metrics.get(k)) for k, _ in columns)
                         + f" | {r.seconds:.2f} |")
    lines += ["", _pair_sentence(result), *precision_lines(result.match_precision), ""]
    if result.agreement:
        names = result.agreement["names"]
        lines += [f"**{agreement_text(result.agreement)}**", "",
                  f"NSGD between the estimators (0 = the same epipolar geometry, FM-Bench's measure; below "
                  f"{result.agreement.get('threshold', NSGD_RECALL_THRESHOLD):g} they agree):", "",
                  "| | " + " | ".join(names) + " |", "|---|" + "--:|" * len(names)]
        lines += [f"| {a} | " + " | ".join(fmt(v) for v in row) + " |" for a, row in zip(names, result.agreement["matrix"])]
        lines.append("")
    lines += [f"- **{r.name} failed**: {r.error}" for r in result.estimators if r.error]
    lines += [f"- {n}" for n in result.notes if n not in suspect]
    lines.append("- One tab per estimator: its keypoints coloured by its residual (viridis, yellow = ≥ "
                 f"{L.RESIDUAL_MAX_PX:g} px off its line), its lines and epipole in its colour, the ground truth's white.")
    if probe_steps:
        lines.append(f"- **probe** tab: press play (or drag the `{L.PROBE_TIMELINE}` time cursor) to walk "
                     f"{probe_steps} matches, the most telling first (each step says by what; near-duplicates skipped): "
                     "each step rings one match (yellow, joined between the images) and draws its epipolar line under "
                     f"every F, thinner in estimator order; the zoomed views show each end {L.PROBE_ZOOM_PX:g} px around "
                     f"with a {L.PROBE_RING_PX:g} px ring: a line that misses it is more than {L.PROBE_RING_PX:g} px off "
                     "there (ground truth white).")
    lines.append("- SED: symmetric epipolar distance, median over the evaluation matches; rot/trans: pose error "
                 "from E = K_bᵀ F K_a; inliers: share of all matches; time s: the estimator's run time; the other "
                 "metrics: `fviz inspect pair ... --json`.")
    for r in result.estimators:
        if r.F is not None:
            F = r.F / np.linalg.norm(r.F)
            lines += ["", f"F {r.name} (unit norm)", "```", np.array2string(F, precision=5, suppress_small=False), "```"]
    return "\n".join(lines)


def estimator_caption(r, result: PairResult) -> str:
    """An estimator tab's numbers, below image b: "ransac: SED 0.246 px | rotation 0.172° | ..."."""
    m = r.metrics
    return (f"{r.name}: SED {fmt(m.get('sed_median'))} px | rotation {fmt(m.get('rot_err_deg'))}° | translation "
            f"{fmt(m.get('trans_err_deg'))}° | NSGD {fmt(m.get('nsgd'))} | inliers {int(m.get('n_inliers', 0))} of "
            f"{result.n_matches} ({fmt(100 * m.get('inlier_ratio', np.nan), 2)} %) | keypoints: its residual, dark blue "
            f"on its line to yellow >= {L.RESIDUAL_MAX_PX:g} px (scale below)")


def caption_strip(size_a: tuple[int, int], size_b: tuple[int, int], r, result: PairResult) -> tuple:
    """The estimator's numbers below the images (in image b's frame), as a labelled invisible strip:
    (strip, colour, radius, label)."""
    at = below_images(size_a, size_b, 18.0)
    return np.stack([at, at]), rgb(L.LABEL_OFF_PHOTO), 0.0, estimator_caption(r, result)


def epipole_name_strip(cross: np.ndarray, label: str, size: tuple[int, int], unit: float = 1.0) -> tuple:
    """An estimator tab's epipole name as a labelled invisible strip 34 screen px above its cross (below it near
    the top edge), its box inside the image (:func:`fviz.record.marks.place_tags`): (strip, colour, radius, label).
    Rerun writes a label in its strip's colour: black, on its light box, reads on any photo."""
    at = cross.mean(axis=(0, 1))
    at = place_tags([at + (0.0, -34.0 * unit if at[1] > 50.0 * unit else 22.0 * unit)], [label], size, unit)[0]
    return np.stack([at, at]), rgb(L.LABEL_ON_PHOTO), 0.0, label


def suspect_reference(notes: Sequence[str]) -> str | None:
    """The F to trust instead of the ground truth when the notes say it is suspect (None otherwise)."""
    return next((n.rpartition("(reference: ")[2].rstrip(")") for n in notes if n.startswith(GT_SUSPECT_NOTE)), None)


def suspect_notice(notes: Sequence[str]) -> str:
    """The overview's warning when the notes say the ground truth is suspect ("" otherwise)."""
    ref = suspect_reference(notes)
    return "" if ref is None else f"GROUND TRUTH SUSPECT: thick labelled lines = REFERENCE, {ref}'s F (summary) - "


def reference_label(name: str) -> str:
    return f"thick lines: REFERENCE = {name}'s F (the ground truth is suspect)"


def log_pair_text(rec, result: PairResult, text: str | None = None) -> None:
    """pair/info, the summary, the metrics table and the estimators' errors of the pair at the current time."""
    import rerun as rr

    rec.log(L.PAIR_INFO, rr.TextDocument(result.pair.get("name", "")))
    rec.log(L.SUMMARY, rr.TextDocument(text or pair_markdown(result), media_type="text/markdown"))
    log_metrics_table(rec, result)
    for r in result.estimators:
        if r.error:
            rec.log(L.error(r.name), rr.TextLog(f"{r.name} failed: {r.error}", level="ERROR"))


def log_metrics_table(rec, result: PairResult) -> None:
    """``pair/metrics``: the estimators' names and one column per metric, NaN where an estimator failed."""
    import rerun as rr

    keys = sorted({k for r in result.estimators for k in r.metrics})
    columns = {k: np.array([r.metrics.get(k, np.nan) if not r.error else np.nan for r in result.estimators], float)
               for k in keys}
    rec.log(L.PAIR_METRICS, rr.AnyValues(estimators=names_of(result), **columns))
