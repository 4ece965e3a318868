"""Run estimators over every pair of a selection (what ``fviz eval`` and ``fviz triage`` do).

A run lives in one ``--out-dir``::

    run.json         the run's configuration (selection, estimator options, the F of the mean-F baselines)
    results.jsonl    one JSON record per finished pair, appended and flushed as pairs finish: the
                     source of truth (``--resume`` skips the pairs it holds and adds only the estimators a
                     pair lacks; a later record of a pair supersedes an earlier one; a line cut by a crash,
                     a line that is not a record, and a record whose fingerprint of settings, pair and
                     inputs (the pair's pairs-file line, COLMAP cameras and poses, --matches / --gt-matches
                     files, by content) is not the run's are ignored, with a warning)
    metrics.csv      PairResult.rows() of every pair: one row per pair x estimator, ``gt`` included
    metrics.parquet  the same rows
    summary.md       standard figures (pose AUC, NSGD recall, median SED / Sampson, failures), per-estimator
                     statistics and the paper-style table
    summary.json     the standard figures, machine-readable
    eval.rrd         every pair on the ``pair`` timeline: pair/info, summary, errors, metric series
    pairs/NNNNNN.npz with ``--full`` only: matches, inlier masks and residuals, so that eval.rrd can
                     carry each pair's full inspect payload (images re-read from the source)

The four reports are regenerated from results.jsonl at the end of every run, an interrupted one
included, so they are always complete up to the last finished pair.

Speed: pairs are sorted frame-major; worker processes (started once, importing while the run is
prepared) take one pair at a time from a frame-aware schedule (:class:`fviz.run.execute.FrameSchedule`):
a pair detects the frames nobody has detected yet and hands their features to the later pairs that
share them, so every frame is detected exactly once (the ``detections`` field of each record), on
whichever worker is free. Deep estimators run in batches on the GPU when CUDA is present.
Memory: a worker loads one pair at a time; the schedule holds features of a bounded window of
frames; the main process keeps only file offsets of results.jsonl and per-metric floats for the summary.
"""

_EXPORTS = {
    "RunConfig": "config", "Selection": "config", "parse_shard": "config", "PairEvaluator": "evaluator",
    "run_eval": "execute", "log_summary_pair": "recording", "merge_runs": "merge", "write_reports": "reports",
    "ResultStore": "store", "read_config": "store", "result_from_record": "store",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    """The run's public names, imported on first use: ``fviz.run.prestart`` starts workers before anything heavy
    is imported, and importing it must not import the rest of the run."""
    if name in _EXPORTS:
        import importlib

        return getattr(importlib.import_module(f"fviz.run.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'fviz.run' has no attribute {name!r}")
