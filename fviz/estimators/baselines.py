"""Baselines that estimate nothing from the pair's content.

- ``ahead``: straight-ahead motion without rotation, F = K_b^-T [z]x K_a^-1, from the cameras alone;
- a constant F, the mean ground-truth F of some selection of pairs (:func:`mean_fundamental`): of the
  evaluated pairs themselves it is an oracle (``oracle-mean``: it has seen the test labels); of other
  sequences (``mean:SEL``) it is a fair prior.

:func:`deep_versus_ahead` says whether a ``deep`` estimate beats ``ahead`` on one pair (its result rows).
"""

from __future__ import annotations

from typing import Callable, Iterable

import numpy as np

from fviz.errors import FvizError


def ahead(pair, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """F of pure forward motion (R = I, t = z) between the pair's cameras; ignores the matches."""
    from fviz.geometry import fundamental_from_motion

    if pair.K_a is None or pair.K_b is None:
        raise ValueError("needs the cameras' intrinsics (K), which this pair lacks")
    return fundamental_from_motion(pair.K_a, pair.K_b, np.eye(3), np.array([0.0, 0.0, 1.0]))


ahead.needs_K = True  # see fviz.estimators.base.missing_K


def mean_fundamental(Fs: Iterable[np.ndarray]) -> np.ndarray:
    """The mean of F matrices up to scale and sign: each FBN-normalized and sign-aligned with the first,
    averaged, made rank 2 and normalized again."""
    from fviz.geometry import enforce_rank2, normalize

    acc, ref, n = np.zeros((3, 3)), None, 0
    for F in Fs:
        F = normalize(F, "fbn")
        ref = F if ref is None else ref
        acc += F if np.sum(F * ref) >= 0 else -F
        n += 1
    if n == 0:
        raise FvizError("no pair selected")
    return normalize(enforce_rank2(acc / n), "fbn")


def constant_estimator(F: np.ndarray) -> Callable:
    """The same F for every pair, whatever the images and matches."""
    F = np.asarray(F, dtype=np.float64).reshape(3, 3)

    def constant(pair, x_a, x_b):
        return F

    return constant


def _is_deep(name: str) -> bool:
    return name == "deep" or name.startswith(("deep-", "deep:"))


def _row(row) -> dict:
    """A result row as a dict (``name``, ``error``, ``metrics``): a results.jsonl row, or an EstimatorResult."""
    return row.to_dict() if hasattr(row, "to_dict") else dict(row)


def deep_versus_ahead(rows, metric: str = "sed_median", tie_rel: float = 0.05) -> dict | None:
    """Whether a ``deep`` estimate beats the ``ahead`` constant on one pair, from that pair's result rows (dicts
    with ``name``, ``error``, ``metrics``, as in results.jsonl, or :class:`fviz.evaluate.EstimatorResult`).

    Lower ``metric`` is better (``sed_median``, ``pose_err_deg``, ...). ``deep`` beats ``ahead`` when its value is
    lower by more than ``tie_rel`` of the larger one (``fviz compare``'s tie); a ``deep`` without a value (no F)
    does not beat it.  Returns None when the rows hold no ``deep`` estimate or no ``ahead`` figure to set it
    beside; else {"deep": its name, "beats": bool, "deep_value", "ahead_value", "metric", "text"}, ``text`` one
    line: "deep 1.2 px vs ahead 3.4 px median SED: beats the constant" or "... : no better than the constant"."""
    import math

    rows = [_row(r) for r in rows]
    deep = next((r for r in rows if _is_deep(str(r.get("name", "")))), None)
    ahead_row = next((r for r in rows if r.get("name") == "ahead"), None)

    def value(r) -> float:
        v = None if r is None or r.get("error") else (r.get("metrics") or {}).get(metric)
        return math.nan if v is None else float(v)

    a, d = value(ahead_row), value(deep)
    if deep is None or not math.isfinite(a):
        return None
    wins = math.isfinite(d) and d < a and (a - d) > tie_rel * max(abs(a), abs(d))
    unit = {"sed_median": " px", "pose_err_deg": " deg", "rot_err_deg": " deg"}.get(metric, "")
    shown = f"{d:.3g}{unit}" if math.isfinite(d) else "no value"
    text = (f"{deep['name']} {shown} vs ahead {a:.3g}{unit} {metric}: "
            + ("beats the constant" if wins else "no better than the constant"))
    return {"deep": deep["name"], "beats": bool(wins), "deep_value": d, "ahead_value": a, "metric": metric, "text": text}
