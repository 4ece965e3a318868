"""Reports regenerated from results.jsonl: metrics.csv / .parquet, summary.md, eval.rrd; and merging
the results of several runs (shards) into one."""

from __future__ import annotations

import csv
import json
import math
from array import array
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from fviz.atomic import WriteError, replacing, write_text
from fviz.diagnose import gt_bias, pair_epipole_offset
from fviz.errors import Interrupted
from fviz.evaluate import GT_NAME
from fviz.failures import Failures, failure_markdown
from fviz.run.config import (  # noqa: E402  (a refused merge names the flags)
    CSV_FILE,
    INT_COLUMNS,
    PAPER_COLUMNS,
    PAPER_NORMS,
    PARQUET_FILE,
    PERCENTILES,
    RESULTS_FILE,
    RRD_FILE,
    SUMMARY_FILE,
    SUMMARY_JSON,
    SUMMARY_METRICS,
    TEXT_COLUMNS,
    RunConfig,
)
from fviz.run.figures import (  # noqa: F401 (re-exported: table, api and tests read them here)
    BASELINE_NOTE,
    EPI_CAVEAT,
    FIGURE_KEYS,
    UNDEFINED,
    UNDEFINED_COLUMN,
    WITH_POSE,
    _display,
    _fmt,
    figures_known,
    figures_markdown,
    row_failed,
    row_kind,
    standard_figures,
)
from fviz.run.recording import iter_rows, write_recording
from fviz.run.store import (
    ResultStore,
)
from fviz.verdicts import ERRORS, fail_rule


def _columns(rows_iter: Iterable[dict[str, Any]]) -> list[str]:
    cols: dict[str, None] = {}
    for row in rows_iter:
        cols.update(dict.fromkeys(row))
    return list(cols)


def _arrow_schema(columns: list[str]):
    import pyarrow as pa

    return pa.schema([(c, pa.string() if c in TEXT_COLUMNS else pa.int64() if c in INT_COLUMNS else pa.float64())
                      for c in columns])


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
