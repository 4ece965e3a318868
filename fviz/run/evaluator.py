"""One pair of a run evaluated: :class:`PairEvaluator` (one per worker process, or in the main process), the task it
is given (:class:`PairTask`) and the record it returns (a results.jsonl line)."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from fviz.atomic import WriteError
from fviz.data.pair import PairId
from fviz.errors import FvizError
from fviz.evaluate import MIN_MATCHES, too_few_matches
from fviz.run.config import RunConfig, resolve_estimators
from fviz.run.store import payload_path, save_payload

CACHE_FRESH, CACHE_NOTES = "_cache_fresh", "_cache_notes"  # a record's keys the main process takes off


def error_message(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text if isinstance(exc, FvizError) else f"{type(exc).__name__}: {text}"


def new_record(config: RunConfig, index: int, pid: PairId) -> dict[str, Any]:
    """A results.jsonl record before evaluation (``error`` and ``result`` still empty)."""
    ref = pid.to_dict()
    return {"index": index, "key": pid.name, "ref": ref, "fingerprint": config.fingerprint(ref),
            "estimators": config.estimator_names(), "error": None, "result": None}


class PairEvaluator:
    """Evaluates pairs of one run, keeping features of recent frames (one per worker process)."""

    def __init__(self, config: RunConfig, out_dir: Path, detect_threads: int = 2, batched: tuple[str, ...] = ()):
        from fviz.diagnose import diagnose
        from fviz.estimators.features import FeatureCache
        from fviz.run.hloc_cache import RunCache, digest

        self.config, self.out_dir = config, Path(out_dir)
        self.source = config.selection.source()
        self.batched: dict = {}  # the current task's results of estimators run in batches elsewhere
        self.estimators = self._resolve(config, batched)
        self.features = config.options.feature_config()
        self.cache = FeatureCache(self.features, max_items=config.cache_items(), threads=detect_threads,
                                  fingerprint=digest)  # the run folder's features.h5 names the pixels
        self.disk = RunCache(self.out_dir, self.features)  # features.h5 / matches.h5 of the run folder
        self.cached: tuple[list, int, int] = ([], 0, 0)  # the last pair's (new cache entries, features read, matches read)
        self.diagnose = diagnose

    def _resolve(self, config: RunConfig, batched: tuple[str, ...]) -> list[tuple[str, Callable]]:
        """The run's estimators; those in ``batched`` (display names) return the F the task brings."""
        from dataclasses import replace

        from fviz.estimators.registry import display_name

        local = replace(config, options=replace(config.options, names=tuple(
            n for n in config.options.names if display_name(n) not in batched)))
        resolved = dict(resolve_estimators(local))

        def given(name: str) -> Callable:
            def estimate(pair, x_a, x_b):
                F, _ = self.batched[name]
                if isinstance(F, str):
                    raise RuntimeError(F)
                return F

            estimate.__name__ = name
            return estimate

        return [(name, resolved[name] if name in resolved else given(name)) for name in config.estimator_names()]

    def evaluate(self, pid: PairId, only: tuple[str, ...] | None = None):
        """(Pair, PairResult) with the full payload (what inspect and triage.rrd show), of the estimators
        named in ``only`` (display names; default all)."""
        from fviz.evaluate import evaluate_pair

        pair = self.source.load(pid)
        estimators = [(n, fn) for n, fn in self.estimators if only is None or n in only]
        matcher = self.disk.prepare(pair, self.cache) if pair.matches is None else None
        result = evaluate_pair(pair, estimators, self.features, self.config.norm, self.config.eval_threshold,
                               self.config.options.threshold, cache=self.cache, timeout=self.config.estimator_timeout,
                               matcher=matcher)
        self.cached = self.disk.collect(pair, self.cache) if matcher is not None else ([], 0, 0)
        return pair, result

    def record(self, index: int, pid: PairId, only: tuple[str, ...] | None = None) -> dict[str, Any]:
        """One line of results.jsonl; never raises for a bad pair (the error is in the record)."""
        t0, misses = time.perf_counter(), self.cache.misses
        rec = new_record(self.config, index, pid)
        if only is not None:
            rec["estimators"] = [n for n in rec["estimators"] if n in only]
        try:
            pair, result = self.evaluate(pid, only)
            rec["result"] = result.to_dict()
            if too_few_matches(result):
                rec["error"] = f"only {result.n_matches} matches ({MIN_MATCHES} needed)"
            rec["diagnostics"] = self.diagnose(pair, result, two_view=False)  # triage adds it where it lists the pair
            if self.config.full:
                path = payload_path(self.out_dir, index)
                save_payload(path, result)
                rec["payload_bytes"] = path.stat().st_size  # resume re-evaluates a pair whose payload is cut
        except WriteError:  # a full disk is not the pair's fault: the run stops (--resume finishes it)
            raise
        except Exception as exc:  # one bad pair must not stop the run
            rec["error"] = error_message(exc)
        fresh, n_features, n_matches = self.cached if rec["result"] is not None else ([], 0, 0)
        rec.update(detections=self.cache.misses - misses, cached_features=n_features, cached_matches=n_matches,
                   seconds=time.perf_counter() - t0, finished_at=time.time(), worker=os.getpid())
        rec[CACHE_FRESH], rec[CACHE_NOTES] = fresh, dict(self.disk.notes)  # for the main process, not results.jsonl
        self.cached = ([], 0, 0)
        self.disk.notes.clear()
        return rec

    def run_task(self, task: "PairTask") -> tuple[dict[str, Any], dict]:
        """A scheduled pair: its record and the features of ``task.keep`` it detected."""
        self.cache.clear()
        self.cache.put(task.given)
        self.batched = task.batched
        rec = self.record(task.index, task.pid, task.only)
        for est in (rec["result"] or {}).get("estimators", []):
            if est["name"] in task.batched:
                est["seconds"] = task.batched[est["name"]][1]  # its share of the batch, not the look-up
        kept = {k: f for k in task.keep if (f := self.cache.peek(k)) is not None}
        self.cache.clear()
        return rec, kept


# ------------------------------------------------------------------------------ scheduling


@dataclass
class PairTask:
    """One pair to evaluate with the features already detected for it (``given``); of the frames it
    detects itself, ``keep`` are needed by later pairs and come back to the scheduler."""

    index: int
    pid: PairId
    given: dict = field(default_factory=dict)
    keep: tuple[str, ...] = ()
    detects: frozenset = frozenset()
    batched: dict = field(default_factory=dict)  # estimator name -> (F or error text, seconds), see DeepBatches
    only: tuple[str, ...] | None = None  # the estimators to run (those the pair's record lacks); None: all
