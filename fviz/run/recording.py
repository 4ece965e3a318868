"""A run's recording (eval.rrd): every pair on the `pair` timeline (its verdict, summary, metrics, errors, and with
``--full`` its images), the run's curves and summary, and the blueprint."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterator

from fviz.data.pair import PairId
from fviz.evaluate import PairResult
from fviz.run.config import RunConfig
from fviz.run.store import ResultStore, load_payload, payload_ok, payload_path, read_records, record_rows, result_from_record


def _pair_text(rec: dict[str, Any], result: PairResult) -> str:
    """The per-pair Markdown: inspect's summary, or the reason a pair failed as a whole."""
    from fviz.record.pair_text import pair_markdown

    if rec.get("result") is None:
        return f"# {rec['key']}\n\n**pair error** (not evaluated): {rec['error']}\n"
    text = pair_markdown(result)
    return text + (f"\n\n**pair error**: {rec['error']}\n" if rec["error"] else "")


def log_summary_pair(rec_stream, index: int, rec: dict[str, Any], result: PairResult, motion: bool = True) -> None:
    """The light per-pair payload at ``pair`` = index: verdict, name, summary, metrics, errors, series (and with
    ``motion`` the motion tracks)."""
    import rerun as rr

    from fviz.record import layout as L
    from fviz.record.pair_text import log_pair_text
    from fviz.record.run_plots import log_series
    from fviz.verdicts import pair_verdict

    rec_stream.set_time(L.TIMELINE, sequence=index)
    rec_stream.log(L.VERDICT, rr.TextDocument(pair_verdict(rec).markdown(), media_type="text/markdown"))
    log_pair_text(rec_stream, result, _pair_text(rec, result))
    log_series(rec_stream, result, motion)


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
    from fviz.record.pair_recording import log_pair
    from fviz.record.run_plots import CURVE_METRICS, log_curves, log_static, ranges_of_values, series_values
    from fviz.record.writer import RecordingWriter

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


def iter_rows(out_dir: Path, config: RunConfig, entries: list | None = None
              ) -> Iterator[tuple[dict[str, Any], PairResult, list[dict[str, Any]]]]:
    """(record, its PairResult, its CSV rows) of each pair, by index; ``entries``: the run's
    (:meth:`ResultStore.latest`) when the caller has them already (results.jsonl is then not scanned again)."""
    if entries is None:
        entries = list(ResultStore(out_dir, config).latest().values())
    for rec in read_records(entries):
        result = result_from_record(rec, config)
        yield rec, result, record_rows(rec, result)
