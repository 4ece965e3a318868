"""Edit a pair's matches and re-estimate: what the page's and the notebook's edit tools call.

    result = fviz.inspect_pair(pair, ("8point", "ransac", "magsac"))
    fewer = fviz.reestimate(pair, result, keep)                  # keep: (N,) bool over result.matches
    looser = fviz.reestimate(pair, result, threshold={"magsac": 3.0})
    ed = fviz.edit(pair, result)                                 # an EditSession: exclude, restore, set, export
    ed.exclude_above(5.0, under="gt"); ed.export("edited/")

Every estimator runs again as :func:`fviz.inspect_pair` ran it (the same functions: a network loads once), on the
matches kept, and is scored, diagnosed and judged the same way.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from fviz.api.names import python_errors
from fviz.api.pairs import Inspected, check_result_of, judged
from fviz.data.pair import Pair
from fviz.errors import FvizError

if TYPE_CHECKING:  # pragma: no cover
    from fviz.editing import EditSession
    from fviz.evaluate import PairResult


def _per_estimator(value, names: list[str], what: str) -> dict[str, Any]:
    if value is None:
        return {}
    if isinstance(value, Mapping):
        unknown = [n for n in value if n not in names]
        if unknown:
            raise FvizError(f"{what}: {', '.join(map(str, unknown))} is not an estimator of this result ({', '.join(names)})")
        return dict(value)
    return {n: value for n in names}


def _resolved(inspected: Inspected, settings: dict[str, dict[str, Any]]) -> list:
    """The inspected estimators, those with other settings resolved again from their spec."""
    out = []
    for name, fn in inspected.ests:
        s = {k: v for k, v in settings.get(name, {}).items() if v is not None}
        if not s:
            out.append((name, fn))
            continue
        if name not in inspected.specs:
            raise FvizError(f"threshold / max_iters of {name}: your function takes none (only fviz's estimators do)")
        if s.get("threshold", 1.0) <= 0 or s.get("max_iters", 1) < 1:
            raise FvizError(f"{name}: threshold must be > 0 px and max_iters >= 1")
        opts = replace(inspected.options, names=(inspected.specs[name],), **s)
        out.append((name, opts.estimators()[0][1]))
    return out


@python_errors
def reestimate(pair: Pair, result: PairResult, keep: np.ndarray | None = None, *,
               threshold: float | Mapping[str, float] | None = None,
               max_iters: int | Mapping[str, int] | None = None) -> PairResult:
    """Run every estimator of ``result`` again on the matches ``keep`` selects, with other robust settings if given.

    Args:
        pair: the pair ``result`` was computed on.
        result: its :func:`fviz.inspect_pair` result (the estimators, options and matches come from it).
        keep: (N,) bool over ``result.matches`` (True: kept) or the indices kept; None: every match.
        threshold: the robust estimators' inlier threshold (px), one for all or ``{name: px}``.
        max_iters: their iteration cap, one for all or ``{name: n}``.

    Returns:
        A new PairResult (the paper's protocol on the kept matches, diagnosis, verdict), whose ``matches`` are the
        kept ones, in order.
    """
    check_result_of(pair, result)
    inspected: Inspected | None = getattr(result, "_inspected", None)
    if inspected is None or result.matches is None:
        raise FvizError("result: not a result of fviz.inspect_pair (with matches) in this session: evaluate the pair with it first")
    n = len(result.matches)
    keep = np.ones(n, bool) if keep is None else np.asarray(keep)
    if keep.dtype == bool:
        if keep.shape != (n,):
            raise FvizError(f"keep: a mask needs {n} entries (one per match), got shape {keep.shape}")
        idx = np.flatnonzero(keep)
    elif np.issubdtype(keep.dtype, np.integer) and keep.ndim == 1 and (not keep.size or (keep.min() >= 0 and keep.max() < n)):
        idx = np.unique(keep)
    else:
        raise FvizError(f"keep: a (N,) bool mask or indices from 0 to {n - 1}")
    names = [name for name, _ in inspected.ests]
    settings: dict[str, dict[str, Any]] = {}
    for key, value in (("threshold", threshold), ("max_iters", max_iters)):
        for name, v in _per_estimator(value, names, key).items():
            settings.setdefault(name, {})[key] = v
    return _evaluated(pair, result, idx, settings)


def _evaluated(pair: Pair, result: PairResult, idx: np.ndarray, settings: dict[str, dict[str, Any]]) -> PairResult:
    """``result``'s estimators (those with ``settings`` resolved again) on its matches at ``idx``, judged."""
    from fviz.evaluate import evaluate_pair

    inspected: Inspected = result._inspected
    ests = _resolved(inspected, settings)
    new = evaluate_pair(pair, ests, inspected.options.feature_config(), inspected.norm, inspected.eval_threshold,
                        inspected.threshold, timeout=inspected.timeout, matches=result.matches.take(idx))
    new.n_keypoints = result.n_keypoints
    return judged(pair, replace(inspected, ests=ests), new)


@python_errors
def edit(pair: Pair, result: PairResult, rec: Any = None, *, index: int = 0, lines: int = 30, probe: int = 20,
         clicks: Any = None, legend: bool = True) -> EditSession:
    """An :class:`fviz.editing.EditSession` on ``result``'s matches: ``exclude``, ``exclude_above``, ``exclude_box``,
    ``restore``, ``toggle``, ``set`` (threshold / max_iters), ``reset``, ``export``; each returns the new result
    (:func:`reestimate`) and, with ``rec`` (a ``rerun.RecordingStream``), draws it at ``index`` as
    :func:`fviz.log_result` does, the excluded matches as grey dots; ``clicks``: the viewer's
    :class:`fviz.interactive.ClickSession`, answered with the new F's; ``legend`` False: the viewer has the residual
    legend from its file (fviz's page)."""
    from fviz.editing import EditSession

    check_result_of(pair, result)
    if getattr(result, "_inspected", None) is None or result.matches is None:
        raise FvizError("result: not a result of fviz.inspect_pair in this session: evaluate the pair with it first")

    def estimate(keep: np.ndarray, settings: dict) -> Any:
        return _evaluated(pair, result, np.flatnonzero(keep), settings)

    return EditSession(pair, result, estimate, rec, index, clicks, lines=lines, probe=probe, legend=legend)
