"""One pair of a run, again, on demand: its record found by index or name (:func:`find_record`), the pair loaded
from the run's source, its matches read from the run's cache (features.h5 / matches.h5; recomputed with the run's
feature settings where the cache lacks them), its estimators run as the run ran them, and the F's checked against
the record (:func:`reopen`); two runs' results on one pair as one result (:func:`versus`)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from fviz.data.pair import Pair, PairId
from fviz.errors import FvizError
from fviz.evaluate import GT_NAME, PairResult
from fviz.run.config import RunConfig

F_TOL = 1e-9  # largest difference of two F's (each scaled to unit norm, sign aligned) that is the same F


@dataclass
class Reopened:
    """A run's pair evaluated again: the pair, its result, the estimators as run (``ests``: [(name, fn)]; ``specs``:
    name -> spec, to resolve one again with other settings), the run's record and configuration."""

    pair: Pair
    result: PairResult
    ests: list
    specs: dict
    record: dict[str, Any]
    config: RunConfig


def find_record(out_dir: Path, config: RunConfig, which: int | str, what: str = "pair") -> dict[str, Any]:
    """The record of pair ``which`` of the run in ``out_dir``: its index on the ``pair`` timeline (an int or digits),
    its name, or the end of its name after a "/" when one pair's name ends so; a one-line error naming ``what``."""
    from fviz.run.store import ResultStore, read_records

    entries = ResultStore(out_dir, config).latest()
    if not entries:
        raise FvizError(f"{what} {which}: the run in {out_dir} has no pair yet")
    by_index = {e.index: key for key, e in entries.items()}
    text = str(which)
    if isinstance(which, (int, np.integer)) or text.isdigit():
        key = by_index.get(int(text))
    else:
        ends = [k for k in entries if k == text or k.endswith("/" + text.strip("/"))]
        key = ends[0] if len(ends) == 1 else None
        if len(ends) > 1:
            raise FvizError(f"{what} {which}: {len(ends)} pairs of the run end so ({ends[0]}, {ends[1]}, ...): give the "
                            "whole name or the index")
    if key is None:
        first, last = min(by_index), max(by_index)
        raise FvizError(f"{what} {which}: not a pair of the run in {out_dir} ({len(entries)} pair"
                        f"{'s' * (len(entries) != 1)}: an index {first}..{last} or a name such as {by_index[first]})")
    return next(read_records([entries[key]]))


def reopen(out_dir: Path, config: RunConfig, which: int | str, what: str = "pair", evaluator=None) -> Reopened:
    """Pair ``which`` of the run (:func:`find_record`) evaluated again as the run evaluated it: -> :class:`Reopened`,
    whose result's notes say where its matches came from when not from the run's cache, and which F differs from
    the one results.jsonl stored (none should: the estimators are seeded). ``evaluator``: the run's
    :class:`fviz.run.evaluator.PairEvaluator` to use (kept by a caller that reads many pairs: a network loads once)."""
    from fviz.run.evaluator import PairEvaluator

    rec = find_record(Path(out_dir), config, which, what)
    if rec.get("result") is None:
        raise FvizError(f"{what} {which}: {rec['key']} was not evaluated in the run ({rec['error']})")
    names = [e["name"] for e in rec["result"]["estimators"] if e["name"] != GT_NAME]
    evaluator = evaluator or PairEvaluator(config, Path(out_dir))
    evaluator.disk.notes.clear()
    try:
        pair, result = evaluator.evaluate(PairId.from_dict(rec["ref"]), tuple(names))
    except FvizError as exc:
        raise FvizError(f"{what} {which}: {rec['key']} cannot be read again: {exc}") from None
    result.notes += [f"{note} ({n}x)" if n > 1 else note for note, n in evaluator.disk.notes.items()]
    if pair.matches is None and not evaluator.cached[2]:
        result.notes.append(f"matches computed again with the run's feature settings ({config.options.features}): "
                            "the run's matches.h5 has none for this pair")
    result.notes += differing_fs(result, rec)
    ests = [(n, fn) for n, fn in evaluator.estimators if n in names]
    specs = {n: s for n, s in zip(config.estimator_names(), config.options.names) if n in names}
    return Reopened(pair, result, ests, specs, rec, config)


def same_F(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Whether two F's are the same matrix up to scale and sign (both None counts as the same)."""
    if a is None or b is None:
        return a is None and b is None
    a, b = np.asarray(a, float) / np.linalg.norm(a), np.asarray(b, float) / np.linalg.norm(b)
    return bool(min(np.abs(a - b).max(), np.abs(a + b).max()) <= F_TOL)


def differing_fs(result: PairResult, rec: dict[str, Any]) -> list[str]:
    """A note per estimator whose F (or error) evaluated again is not the one the run's record holds."""
    stored = {e["name"]: e for e in rec["result"]["estimators"]}
    notes = []
    for r in result.estimators:
        s = stored.get(r.name)
        if s is None or same_F(r.F if not r.error else None, s["F"] if not s["error"] else None):
            continue
        if r.error or s["error"]:
            now, then = (r.error or "an F"), (s["error"] or "an F")
            notes.append(f"{r.name}: gave {now} now, {then} in the run (results.jsonl)")
        else:
            a, b = (np.asarray(F, float) / np.linalg.norm(F) for F in (r.F, s["F"]))
            diff = min(np.abs(a - b).max(), np.abs(a + b).max())
            notes.append(f"{r.name}: its F differs from the run's in results.jsonl (largest difference {diff:.2g} of "
                         "unit-norm F's); the run's metrics are those of its own F")
    return notes


# ------------------------------------------------------------------------------ two runs on one pair


def versus(a: Reopened, b: Reopened, labels: tuple[str, str]) -> tuple[PairResult, list, dict]:
    """One result of two runs on one pair: the ground truth once (a's), then every estimator of each run named
    "<label>-<name>", each with its run's own metrics; drawn on a's matches (b's per-match residuals and inliers
    measured on them where b's matches differ, with a note). -> (result, ests, specs) with the names prefixed."""
    from fviz.evaluate import agreement
    from fviz.geometry import epipolar_residuals

    ra, rb = a.result, b.result
    ma, mb = ra.matches, rb.matches
    same_matches = ma is not None and mb is not None and len(ma.x_a) == len(mb.x_a) \
        and np.array_equal(ma.x_a, mb.x_a) and np.array_equal(ma.x_b, mb.x_b)
    rows = [r for r in ra.estimators if r.name == GT_NAME]
    for label, side in zip(labels, (a, b)):
        threshold = side.config.options.threshold
        for r in side.result.estimators:
            if r.name == GT_NAME:
                continue
            r = replace(r, name=f"{label}-{r.name}", metrics=dict(r.metrics))
            if side is b and not same_matches and r.F is not None and ma is not None:
                _, r.residuals_px, sampson = epipolar_residuals(r.F, ma.x_a, ma.x_b)
                r.inliers = sampson < threshold
            rows.append(r)
    notes = [f"{labels[0]} vs {labels[1]}: {note}" for note in _differences(a, b, same_matches)]
    notes += [f"{labels[0]}: {n}" for n in ra.notes] + [f"{labels[1]}: {n}" for n in rb.notes if n not in ra.notes]
    result = replace(ra, estimators=rows, notes=notes, verdict=None,
                     agreement=None if ra.has_gt else agreement(rows, a.pair.size_a, a.pair.size_b))
    ests = [(f"{label}-{n}", fn) for label, side in zip(labels, (a, b)) for n, fn in side.ests]
    specs = {f"{label}-{n}": s for label, side in zip(labels, (a, b)) for n, s in side.specs.items()}
    return result, ests, specs


def _differences(a: Reopened, b: Reopened, same_matches: bool) -> list[str]:
    """What differs between two runs on one pair beyond their estimators: the matches, the evaluation settings."""
    out = []
    if not same_matches:
        out.append(f"the matches differ ({a.result.n_matches} and {b.result.n_matches}): drawn are the first run's; "
                   "each run's metrics are its own, on its own matches")
    ca, cb = a.config, b.config
    for what, va, vb in (("norm", ca.norm, cb.norm), ("eval threshold", ca.eval_threshold, cb.eval_threshold),
                         ("inlier threshold", ca.options.threshold, cb.options.threshold)):
        if va != vb:
            out.append(f"{what} {va} and {vb}: each run's metrics under its own; an edit re-estimates under the first's")
    return out
