"""Reports regenerated from results.jsonl: metrics.csv / .parquet, summary.md, eval.rrd; and merging
the results of several runs (shards) into one."""

from __future__ import annotations

import csv
import json
import math
from array import array
from dataclasses import replace
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from fviz.atomic import WriteError, replacing, write_text
from fviz.data.pair import PairId
from fviz.errors import FvizError, Interrupted
from fviz.diagnose import gt_bias, pair_epipole_offset
from fviz.failures import Failures, failure_markdown
from fviz.verdicts import ERRORS, fail_rule, fails_column
from fviz.evaluate import GT_NAME, PairResult
from fviz.geometry.pose import MIN_POSE_POINTS
from fviz.run.config import _FLAGS, _flatten, _show  # noqa: E402  (a refused merge names the flags)
from fviz.run.config import (
    CSV_FILE, INT_COLUMNS, PAPER_COLUMNS, PAPER_NORMS, PARQUET_FILE, PERCENTILES, RESULTS_FILE, RRD_FILE,
    RUN_FILE, SUMMARY_FILE, SUMMARY_JSON, SUMMARY_METRICS, TEXT_COLUMNS, RunConfig,
)
from fviz.run.store import (
    ResultStore, RunOutcome, holder_of, load_payload, locked, payload_ok, payload_path, read_config, read_records, record_rows,
    result_from_record, write_config,
)



def _columns(rows_iter: Iterable[dict[str, Any]]) -> list[str]:
    cols: dict[str, None] = {}
    for row in rows_iter:
        cols.update(dict.fromkeys(row))
    return list(cols)


def iter_rows(out_dir: Path, config: RunConfig, entries: list | None = None
              ) -> Iterator[tuple[dict[str, Any], PairResult, list[dict[str, Any]]]]:
    """(record, its PairResult, its CSV rows) of each pair, by index; ``entries``: the run's
    (:meth:`ResultStore.latest`) when the caller has them already (results.jsonl is then not scanned again)."""
    if entries is None:
        entries = list(ResultStore(out_dir, config).latest().values())
    for rec in read_records(entries):
        result = result_from_record(rec, config)
        yield rec, result, record_rows(rec, result)


def _arrow_schema(columns: list[str]):
    import pyarrow as pa

    return pa.schema([(c, pa.string() if c in TEXT_COLUMNS else pa.int64() if c in INT_COLUMNS else pa.float64())
                      for c in columns])


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


class _Stats:
    """Finite values per (estimator, metric) for the summary; failures counted per estimator; and per
    pair the FIGURE_KEYS (NaN for a failure) for the standard figures."""

    def __init__(self, keys: Iterable[str]):
        self.keys = frozenset(keys)
        self.values: dict[tuple[str, str], array] = {}
        self.failed: dict[str, int] = {}
        self.pairs = self.pair_errors = 0
        self.order: dict[str, None] = {}
        self.per_pair: dict[str, array] = {}
        self.ground_truth: set[str] = set()  # what the pairs' ground truth is (pose, F, correspondences, none)
        self.precision: dict[str, array] = {}  # match precision per pair (fviz.geometry.precision)
        self.oracle_choice: dict[str, dict[str, int]] = {}  # sweep oracle -> {the grid entry it chose: pairs}
        self.failures = Failures()  # pair and estimator failures grouped by cause (fviz.failures)
        self.pair_gt: dict[str, list[str]] = {}  # per estimator, each pair's ground truth (pose, F, ..., none)
        self.epipole_offsets: list = []  # per pair with forward motion, the tight fits' offset from F_gt (gt_bias)
        self.agreement: dict[tuple[str, str], array] = {}  # no ground truth: per two estimators, each pair's NSGD

    @property
    def gt_bias(self) -> dict[str, Any] | None:
        """The ground truth's bias over the run (:func:`fviz.diagnose.gt_bias`), None when none is found."""
        return gt_bias(self.epipole_offsets)

    @property
    def known(self) -> dict[str, bool]:
        return figures_known(self.ground_truth)

    def add(self, rec: dict[str, Any], rows: list[dict[str, Any]]) -> None:
        self.pairs += 1
        self.failures.add(rec)
        if (offset := pair_epipole_offset(rec)) is not None:
            self.epipole_offsets.append(offset)
        self.ground_truth.update(row["ground_truth"] for row in rows[:1] if row.get("ground_truth"))
        self.pair_errors += rec["error"] is not None
        for key, v in ((rec.get("result") or {}).get("match_precision") or {}).items():
            if v is not None:
                self.precision.setdefault(key, array("d")).append(float(v))
        self._add_oracle_choices((rec.get("result") or {}).get("estimators", []))
        self._add_agreement((rec.get("result") or {}).get("agreement"))
        for row in rows:
            est = row["estimator"]
            self.order[est] = None
            failed = row_failed(est, row["error"], rec["error"])
            if failed:
                self.failed[est] = self.failed.get(est, 0) + 1
            self.per_pair.setdefault(est, array("d")).extend(
                math.nan if failed or row.get(k) is None else float(row[k]) for k in FIGURE_KEYS)
            self.pair_gt.setdefault(est, []).append(row_kind(est, row, failed))
            for key in self.keys:
                v = row.get(key)
                if isinstance(v, float) and math.isfinite(v):
                    self.values.setdefault((est, key), array("d")).append(v)

    def _add_agreement(self, ag: dict[str, Any] | None) -> None:
        """A pair's agreement matrix (no ground truth: NSGD between every two estimates) into per-two series."""
        if not ag:
            return
        names, m = ag["names"], ag["matrix"]
        for i, a in enumerate(names):
            for j in range(i + 1, len(names)):
                if m[i][j] is not None and math.isfinite(m[i][j]):
                    self.agreement.setdefault((a, names[j]), array("d")).append(float(m[i][j]))

    def agreement_table(self) -> dict[str, dict[str, Any]]:
        """Per two estimators ("a - b"), over the pairs where both gave an F: ``pairs``, ``median_nsgd`` and
        ``agree`` (pairs where they agree: NSGD under fviz.verdicts' agreement_nsgd threshold)."""
        rule = fail_rule("agreement_nsgd")
        return {f"{a} - {b}": {"pairs": len(v), "median_nsgd": float(np.median(v)),
                               "agree": int(sum(not rule.fails(x) for x in v))}
                for (a, b), v in self.agreement.items() if len(v)}

    def _add_oracle_choices(self, ests: list[dict[str, Any]]) -> None:
        """Which threshold each sweep oracle chose on a pair: the grid entry with the very same F."""
        from fviz.estimators.sweep import ORACLE_SUFFIX

        for e in ests:
            if e["name"].endswith(ORACLE_SUFFIX) and e.get("F") is not None:
                prefix = e["name"][: -len(ORACLE_SUFFIX)] + "-th"
                same = next((o["name"] for o in ests if o["name"].startswith(prefix) and o is not e and o.get("F") == e["F"]), None)
                if same is not None:
                    counts = self.oracle_choice.setdefault(e["name"], {})
                    counts[same] = counts.get(same, 0) + 1

    def get(self, est: str, key: str) -> np.ndarray:
        return np.asarray(self.values.get((est, key), []), dtype=np.float64)


def write_reports(out_dir: Path, config: RunConfig) -> dict[str, Path]:
    """metrics.csv, metrics.parquet, summary.md and eval.rrd from results.jsonl (each written atomically).

    Each report replaces its previous version only when complete: on Ctrl-C or a write error the
    others keep theirs, and the error says which were rewritten and how to finish (``--resume``)."""
    out_dir = Path(out_dir)
    paths: dict[str, Path] = {}
    try:
        entries = list(ResultStore(out_dir, config).latest().values())  # results.jsonl scanned once
        columns = _columns(row for _, _, rows in iter_rows(out_dir, config, entries) for row in rows)
        stats = _write_tables(out_dir, config, columns, entries)
        paths.update(csv=out_dir / CSV_FILE, parquet=out_dir / PARQUET_FILE)
        paths["summary"] = write_summary(out_dir / SUMMARY_FILE, config, stats)
        paths["summary_json"] = write_text(out_dir / SUMMARY_JSON, json.dumps(summary_document(config, stats), indent=2) + "\n")
        paths["rrd"] = write_recording(out_dir / RRD_FILE, out_dir, config, run_markdown(config, stats), entries)
    except KeyboardInterrupt:
        raise Interrupted(f"while writing the reports: {_reports_kept(out_dir, paths)}") from None
    except WriteError as exc:
        raise WriteError(f"{exc}; {_reports_kept(out_dir, paths)}") from None
    return paths


def _reports_kept(out_dir: Path, rewritten: dict[str, Path]) -> str:
    """Which reports are new, which kept their previous version, and the command that finishes them."""
    names = (CSV_FILE, PARQUET_FILE, SUMMARY_FILE, RRD_FILE)
    new = [n for n in names if out_dir / n in rewritten.values()]
    old = [n for n in names if n not in new and (out_dir / n).is_file()]
    parts = [f"{', '.join(new)} rewritten"] if new else []
    parts += [f"{', '.join(old)} kept {'its' if len(old) == 1 else 'their'} previous version"] if old else []
    parts += [f"{', '.join(n for n in names if n not in new and n not in old)} not written"] \
        if len(new) + len(old) < len(names) else []
    return (f"{'; '.join(parts)}; {RESULTS_FILE} holds every finished pair; "
            f"finish with: fviz eval --out-dir {out_dir} --resume")


def _write_tables(out_dir: Path, config: RunConfig, columns: list[str], entries: list | None = None,
                  batch: int = 2000) -> _Stats:
    import pyarrow as pa
    import pyarrow.parquet as pq

    csv_path, pq_path = out_dir / CSV_FILE, out_dir / PARQUET_FILE
    schema, stats, pending = _arrow_schema(columns), _Stats(SUMMARY_METRICS + PAPER_COLUMNS), []
    with replacing(csv_path) as csv_tmp, replacing(pq_path) as pq_tmp, \
            open(csv_tmp, "w", newline="") as f, pq.ParquetWriter(pq_tmp, schema) as pw:
        writer = csv.DictWriter(f, columns, restval="")
        writer.writeheader()

        def flush():
            pw.write_table(pa.Table.from_pylist(pending, schema=schema))
            pending.clear()

        for rec, _, rows in iter_rows(out_dir, config, entries):
            stats.add(rec, rows)
            writer.writerows(rows)
            pending.extend(_typed(row, columns) for row in rows)
            if len(pending) >= batch:
                flush()
        flush()
    return stats


def _typed(row: dict[str, Any], columns: list[str]) -> dict[str, Any]:
    out = {}
    for c in columns:
        v = row.get(c)
        if c in TEXT_COLUMNS:
            out[c] = None if v is None else str(v)
        elif c in INT_COLUMNS:
            out[c] = None if v is None else int(v)
        else:
            out[c] = None if v is None or v == "" else float(v)
    return out


def _fmt(v: float) -> str:
    return "n/a" if not math.isfinite(v) else f"{v:.4g}"


def _display(est: str) -> str:
    return "ground truth" if est == GT_NAME else est


def summary_markdown(config: RunConfig, stats: _Stats) -> str:
    """Per-estimator statistics of the key metrics and the paper-style EPI table."""
    ests = list(stats.order) or config.series_names()
    o = config.options
    lines = [
        "# fviz eval",
        "",
        f"{config.selection.describe()}" + (f", shard {config.shard[0]}/{config.shard[1]}" if config.shard else "") + ".",
        f"{stats.pairs} pairs ({stats.pair_errors} not evaluated: pair errors); features {o.features} "
        f"(max {o.max_keypoints}, ratio {o.ratio}"
        f"{', mutual' if o.mutual else ''}); robust threshold {o.threshold} px; " + (
            "**no ground truth**: residuals over all matches, the estimators compared with each other (agreement_nsgd)."
            if stats.ground_truth == {"none"} else f"evaluation matches: GT symmetric epipolar distance < {config.eval_threshold} px."),
        f"EPI-ABS / EPI-SQR (`epi_abs`, `epi_sqr`) are per-pair **means** over the evaluation matches, on F normalized by "
        f"**{config.norm.upper()}**; distances in px. Statistics below are over the pairs where the estimator gave an F.",
        "",
        *failure_markdown(stats.failures.document()),
        *([f"**{stats.gt_bias['text'][0].upper()}{stats.gt_bias['text'][1:]}.**", ""] if stats.gt_bias else []),
        "## Standard figures",
        "",
        *figures_markdown(standard_figures(stats.per_pair, ests, stats.known, stats.pair_gt, stats.failed)),
        "",
        *agreement_markdown(stats),
        "## Per estimator",
    ]
    for key in SUMMARY_METRICS:
        lines += ["", f"### {key}", "", f"| estimator | ok | {ERRORS} | mean | median | " + " | ".join(f"p{p}" for p in PERCENTILES) + " |",
                  "|---|---|---|---|---|" + "---|" * len(PERCENTILES)]
        for est in ests:
            v = stats.get(est, key)
            vals = [v.mean(), np.median(v), *(np.percentile(v, p) for p in PERCENTILES)] if len(v) else [math.nan] * (2 + len(PERCENTILES))
            lines.append(f"| {_display(est)} | {stats.pairs - stats.failed.get(est, 0)} | {stats.failed.get(est, 0)} | "
                         + " | ".join(_fmt(x) for x in vals) + " |")
    lines += ["", *time_markdown(stats, ests), "", *precision_markdown(stats), *sweep_markdown(config, stats)]
    lines += [
        "",
        "## Paper-style table",
        "",
        "Means over pairs of the per-pair EPI-ABS and EPI-SQR (themselves means over the evaluation matches), "
        "F normalized by the norm named in each column (FBN: Frobenius norm, ABS: largest absolute entry, "
        "ETR: F33; n/a where undefined, e.g. ETR on rectified stereo pairs where F33 = 0).",
        "",
        "| estimator | " + " | ".join(f"EPI-ABS {n.upper()} | EPI-SQR {n.upper()}" for n in PAPER_NORMS) + " |",
        "|---|" + "---|---|" * len(PAPER_NORMS),
    ]
    for est in ests:
        vals = [stats.get(est, c) for c in PAPER_COLUMNS]
        lines.append(f"| {_display(est)} | " + " | ".join(_fmt(v.mean()) if len(v) else "n/a" for v in vals) + " |")
    lines += ["", EPI_CAVEAT]
    return "\n".join(lines) + "\n"


def agreement_markdown(stats: _Stats) -> list[str]:
    """Without ground truth: how far every two estimators' F are apart over the run (:meth:`_Stats.agreement_table`)."""
    table = stats.agreement_table()
    if not table:
        return []
    threshold = fail_rule("agreement_nsgd").threshold
    lines = ["## Agreement between the estimators (no ground truth)", "",
             f"Per two estimators, over the pairs where both gave an F: the NSGD between their F (FM-Bench's normalized "
             f"distance) and the pairs where they agree (NSGD < {threshold:g}).", "",
             "| estimators | pairs | median NSGD | agree |", "|---|---|---|---|"]
    lines += [f"| {k} | {t['pairs']} | {_fmt(t['median_nsgd'])} | {t['agree']} of {t['pairs']} |" for k, t in table.items()]
    return lines + [""]


def time_table(stats: _Stats, ests: Iterable[str]) -> dict[str, dict[str, float]]:
    """Per estimator (the ground truth left out), median and p90 of its seconds per pair, failures included."""
    out = {}
    for est in ests:
        v = stats.get(est, "seconds")
        if est != GT_NAME:
            out[est] = {"median": float(np.median(v)) if len(v) else math.nan,
                        "p90": float(np.percentile(v, 90)) if len(v) else math.nan}
    return out


def time_markdown(stats: _Stats, ests: Iterable[str]) -> list[str]:
    lines = ["## Time per pair", "", "Wall time of the estimator's call alone (not features or matching), ms; the first "
             "pair of each worker also pays the import of its library (PoseLib, pycolmap, torch).", "",
             "| estimator | median ms | p90 ms |", "|---|---|---|"]
    for est, t in time_table(stats, ests).items():
        lines.append(f"| {est} | {_fmt(1e3 * t['median'])} | {_fmt(1e3 * t['p90'])} |")
    return lines


def precision_markdown(stats: _Stats) -> list[str]:
    """Match precision before any estimator, mean and median over pairs."""
    if not stats.precision:
        return []
    lines = ["## Match precision (before any estimator)", "",
             "Per pair, the share of matches within 1 / 2 / 4 px of the ground-truth epipolar lines (`px_prec`) and under "
             "glue-factory's normalized epipolar error (`epi_prec`, units of the focal length: 1e-3 is ~0.7 px on KITTI); "
             "over pairs:", "", "| measure | mean | median |", "|---|---|---|"]
    for key, v in stats.precision.items():
        v = np.asarray(v)
        lines.append(f"| {key} | {_fmt(float(v.mean()))} | {_fmt(float(np.median(v)))} |")
    return lines


def sweep_curves(config: RunConfig, stats: _Stats) -> dict[str, dict[str, Any]]:
    """Per swept estimator: {threshold text: (display name, standard figures)} in the order run, the per-pair
    oracle's name, and the threshold best over the run by AUC@10 (chosen with the ground truth: an oracle too)."""
    from fviz.estimators.registry import display_names
    from fviz.estimators.sweep import ORACLE, split_threshold

    figures = standard_figures(stats.per_pair, list(stats.order), pair_gt=stats.pair_gt, failures=stats.failed)
    out: dict[str, dict[str, Any]] = {}
    for spec, name in zip(config.options.names, display_names(config.options.names)):
        base, th = split_threshold(spec)
        if th is None or name not in figures:
            continue
        entry = out.setdefault(base, {"curve": {}, "oracle": None, "best": None})
        if th.startswith(ORACLE):
            entry["oracle"] = name
        else:
            entry["curve"][th] = (name, figures[name])
    for entry in out.values():
        if entry["curve"]:
            entry["best"] = max(entry["curve"], key=lambda t: (entry["curve"][t][1]["pose_auc"].get("10", -1), -float(t)))
    return out


def sweep_markdown(config: RunConfig, stats: _Stats) -> list[str]:
    curves = sweep_curves(config, stats)
    if not curves:
        return []
    lines = ["", "## Threshold sweep", "",
             "Each robust estimator at every threshold (px, in its own unit: see docs/estimators.md). *best over "
             "the run*: the threshold of the highest AUC@10°; `-th-oracle`: per pair, the threshold whose F is closest "
             "to the ground truth. Both are chosen with the labels (oracles, as glue-factory's `ransac_th=-1`).", "",
             "| estimator | threshold px | AUC@10° | median SED px | |", "|---|---|---|---|---|"]
    figures = standard_figures(stats.per_pair, list(stats.order), pair_gt=stats.pair_gt, failures=stats.failed)
    for base, entry in curves.items():
        for th, (name, f) in entry["curve"].items():
            lines.append(f"| {base} | {th} | {_fmt(f['pose_auc'].get('10', math.nan))} | {_fmt(f['sed_median'])} | "
                         f"{'*best over the run* (oracle)' if th == entry['best'] else ''} |")
        if entry["oracle"]:
            f = figures[entry["oracle"]]
            chosen = stats.oracle_choice.get(entry["oracle"], {})
            picks = ", ".join(f"{th} px {chosen[n]}" for th, (n, _) in entry["curve"].items() if chosen.get(n))
            lines.append(f"| {base} | per-pair oracle | {_fmt(f['pose_auc'].get('10', math.nan))} | {_fmt(f['sed_median'])} "
                         f"| oracle; chosen per pair: {picks or '-'} |")
    return lines


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


def summary_document(config: RunConfig, stats: _Stats) -> dict[str, Any]:
    """summary.json: the standard figures per estimator, machine-readable (NaN written as null)."""
    ests = list(stats.order) or config.series_names()
    figures = standard_figures(stats.per_pair, ests, stats.known, stats.pair_gt, stats.failed)
    clean = lambda v: v if not isinstance(v, float) or math.isfinite(v) else None  # noqa: E731
    return {
        "selection": config.selection.describe(), "pairs": stats.pairs, "pair_errors": stats.pair_errors,
        "norm": config.norm, "eval_threshold_px": config.eval_threshold,
        "failures": stats.failures.document(),
        "gt_bias": stats.gt_bias,
        "estimators": {e: {k: ({kk: clean(vv) for kk, vv in v.items()} if isinstance(v, dict) else clean(v))
                           for k, v in f.items()} for e, f in figures.items()},
        "seconds": {e: {k: clean(v) for k, v in t.items()} for e, t in time_table(stats, ests).items()},
        "match_precision": {k: clean(float(np.mean(v))) for k, v in stats.precision.items()},
        **({"agreement": stats.agreement_table()} if stats.agreement else {}),
        "threshold_sweep": {b: {"best_over_run_px": e["best"], "oracle": e["oracle"],
                                "names": {t: n for t, (n, _) in e["curve"].items()},
                                "oracle_chose": {t: stats.oracle_choice.get(e["oracle"], {}).get(n, 0)
                                                 for t, (n, _) in e["curve"].items()}}
                            for b, e in sweep_curves(config, stats).items()},
    }


def write_summary(path: Path, config: RunConfig, stats: _Stats) -> Path:
    return write_text(path, summary_markdown(config, stats))


def _pair_text(rec: dict[str, Any], result: PairResult) -> str:
    """The per-pair Markdown: inspect's summary, or the reason a pair failed as a whole."""
    from fviz.record.writer import pair_markdown

    if rec.get("result") is None:
        return f"# {rec['key']}\n\n**pair error** (not evaluated): {rec['error']}\n"
    text = pair_markdown(result)
    return text + (f"\n\n**pair error**: {rec['error']}\n" if rec["error"] else "")


def log_summary_pair(rec_stream, index: int, rec: dict[str, Any], result: PairResult, motion: bool = True) -> None:
    """The light per-pair payload at ``pair`` = index: verdict, name, summary, metrics, errors, series (and with
    ``motion`` the motion tracks)."""
    import rerun as rr

    from fviz.record import layout as L
    from fviz.record.writer import log_pair_text, log_series
    from fviz.verdicts import pair_verdict

    rec_stream.set_time(L.TIMELINE, sequence=index)
    rec_stream.log(L.VERDICT, rr.TextDocument(pair_verdict(rec).markdown(), media_type="text/markdown"))
    log_pair_text(rec_stream, result, _pair_text(rec, result))
    log_series(rec_stream, result, motion)


def run_markdown(config: RunConfig, stats: _Stats) -> str:
    """eval.rrd's summary tab: the run's standard figures (what summary.md opens with), its failures by cause and,
    without ground truth, which estimators agree."""
    ests = list(stats.order) or config.series_names()
    return "\n".join([f"**{config.selection.describe()}**: {stats.pairs} pairs ({stats.pair_errors} not evaluated: pair errors).",
                      "", *figures_markdown(standard_figures(stats.per_pair, ests, stats.known, stats.pair_gt, stats.failed)), "",
                      *failure_markdown(stats.failures.document()), *agreement_markdown(stats),
                      "Tabs: **metrics** (errors on log10 axes) and **motion** (one series per F over the `pair` timeline), "
                      "**curves** (share "
                      "of the pairs below each threshold), and with `--full` the pairs' images. Every figure: summary.md."])


def _curves_with_ground_truth(curves: dict, out_dir: Path, config: RunConfig, entries: list) -> dict:
    """The cumulative curves over the pairs whose ground truth gives the metric (pose error: a pose; the
    others: any), as the standard figures count them: a pair without ground truth is no miss."""
    kinds: dict[str, list[str]] = {}
    for _, _, rows in iter_rows(out_dir, config, entries):
        for row in rows:
            kinds.setdefault(row["estimator"], []).append(row.get("ground_truth") or "pose")
    if all(k == "pose" for ks in kinds.values() for k in ks):
        return curves
    out = {}
    for key, per in curves.items():
        keep = (lambda k: k == "pose") if key == "pose_err_deg" else (lambda k: k != "none")
        kept = {n: [v for v, k in zip(vals, kinds[n]) if keep(k)] if len(kinds.get(n, ())) == len(vals) else vals
                for n, vals in per.items()}
        out[key] = {n: v for n, v in kept.items() if v}  # no curve where no pair has the ground truth it needs
    return out


def write_recording(path: Path, out_dir: Path, config: RunConfig, summary: str = "", entries: list | None = None) -> Path:
    """eval.rrd: every pair on the ``pair`` timeline with its metric series and motion tracks, the cumulative
    error curves and the run's figures (``summary``); with ``--full`` (and a saved payload) also inspect's
    images, keypoints and lines, images re-read from the source."""
    import rerun as rr

    from fviz.record import layout as L
    from fviz.record.writer import (
        CURVE_METRICS, RecordingWriter, log_curves, log_pair, log_static, ranges_of_values, series_values,
    )

    source = config.selection.source() if config.full else None
    names = config.series_names()
    sizes = None
    if entries is None:
        entries = list(ResultStore(out_dir, config).latest().values())
    if config.full:
        first = next((r["result"]["pair"] for r in read_records(entries) if r.get("result")), None)
        if first is not None:
            sizes = (tuple(first["size_a"]), tuple(first["size_b"]))
    values = series_values(result for _, result, _ in iter_rows(out_dir, config, entries))  # the plots' ranges first
    curves = {key: values.get(L.metric(key), {}) for key, *_ in CURVE_METRICS}  # none before the first pair
    curves = _curves_with_ground_truth(curves, out_dir, config, entries)
    ranges = ranges_of_values(values)
    bp = L.blueprint(names, sizes, single_pair=False, ranges=ranges, curves=True, run_summary=True, verdict=sizes is not None)
    with RecordingWriter(path, "fviz-eval", bp) as w:
        log_static(w.rec, names, series=True, legend=sizes is not None, ranges=ranges)
        log_curves(w.rec, curves, L.estimator_colors(names))
        w.rec.log(L.RUN_SUMMARY, rr.TextDocument(summary or "", media_type="text/markdown"), static=True)
        for rec, result, _ in iter_rows(out_dir, config, entries):
            payload = payload_path(out_dir, rec["index"])
            if source is not None and rec.get("result") is not None and payload_ok(payload):
                pair = source.load(PairId(**{k: v for k, v in rec["ref"].items() if k != "name"}))
                log_pair(w.rec, rec["index"], pair, load_payload(payload, result), single_pair=False)
            else:
                log_summary_pair(w.rec, rec["index"], rec, result)
            w.pair_done()
    return path


# ------------------------------------------------------------------------------ merge


def merge_runs(dirs: list[Path], out_dir: Path) -> RunOutcome:
    """Merge the results of shards (or any runs of one configuration) into ``out_dir`` (locked meanwhile)."""
    configs = []
    for d in dirs:
        c = read_config(d)
        if c is None or not (Path(d) / RESULTS_FILE).is_file():
            raise FvizError(f"merge: {d} holds no fviz run ({RUN_FILE} and {RESULTS_FILE} expected)")
        holder = holder_of(Path(d))
        if holder is not None:
            raise FvizError(f"merge: {d} is still being written by {holder}: merge it when that run has finished")
        configs.append(c)
    first = configs[0]
    for d, c in zip(dirs, configs):
        if c.comparable() != first.comparable() or c.estimator_names() != first.estimator_names():
            ours, theirs = _flatten(first.comparable()), _flatten(c.comparable())
            diff = [f"{_FLAGS.get(k, k)} {_show(k, ours.get(k))} in {dirs[0]}, {_show(k, theirs.get(k))} in {d}"
                    for k in sorted(ours.keys() | theirs.keys()) if ours.get(k) != theirs.get(k)]
            if c.estimator_names() != first.estimator_names():
                diff.append(f"--estimator {','.join(first.estimator_names())} in {dirs[0]}, "
                            f"{','.join(c.estimator_names())} in {d}")
            raise FvizError(f"merge: {d} was run with other settings than {dirs[0]}: {'; '.join(diff)}")
    with locked(out_dir):
        return _merge_into(dirs, Path(out_dir), replace(first, shard=None))


def _merge_into(dirs: list[Path], out_dir: Path, config: RunConfig) -> RunOutcome:
    import shutil

    if (out_dir / RESULTS_FILE).exists():
        raise FvizError(f"--out-dir {out_dir} already holds a run: choose an empty folder")
    latest = {}  # key -> Entry; later dirs win
    for d in dirs:
        latest.update(ResultStore(d, config).latest())
    store, failed = ResultStore(out_dir, config), 0
    for rec in read_records(list(latest.values())):
        store.append(rec)
        failed += rec["error"] is not None
        payload = payload_path(latest[rec["key"]].path.parent, rec["index"])
        if payload.is_file():
            with replacing(payload_path(out_dir, rec["index"])) as tmp:
                shutil.copyfile(payload, tmp)
    store.close()
    write_config(out_dir, config)
    outcome = RunOutcome(total=len(config.pairs()), reused=len(latest), computed=0, interrupted=False,
                         out_dir=out_dir, failed=failed)
    outcome.paths = write_reports(out_dir, config)
    return outcome
