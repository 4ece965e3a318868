"""What an estimator is: a callable from a pair and its matches to an F.

    estimate(pair, x_a, x_b) -> F  or  (F, inlier_mask)

pair: :class:`fviz.data.Pair`; x_a, x_b: (M, 2) matched pixel coordinates (x_b^T F x_a = 0);
F: (3, 3); inlier_mask: (M,) bool, or None when the method has no notion of inliers.
Correspondence-free (deep) estimators read ``pair.image_a`` / ``pair.image_b`` and ignore the matches.
The runner (:func:`fviz.estimators.run_estimator`) times the call and turns exceptions and
invalid (NaN, zero) matrices into an :class:`Estimate` with ``error`` set.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

EstimateFn = Callable[..., Any]


@dataclass
class Estimate:
    name: str
    F: np.ndarray | None
    inliers: np.ndarray | None
    seconds: float
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


def run_estimator(name: str, fn: EstimateFn, pair, x_a: np.ndarray, x_b: np.ndarray) -> Estimate:
    """Call one estimator, never raising: failures come back as ``Estimate.error``."""
    from fviz.geometry import is_valid

    t0 = time.perf_counter()
    try:
        out = fn(pair, x_a, x_b)
    except Exception as exc:  # an estimator failing must not stop the others
        error = f"{type(exc).__name__}: {exc}"
        if os.environ.get("FVIZ_DEBUG"):  # fviz --debug: where it raised, for the author of the estimator
            import traceback

            error += "\n" + "".join(traceback.format_exception(exc)).rstrip()
        return Estimate(name, None, None, time.perf_counter() - t0, error)
    seconds = time.perf_counter() - t0
    try:
        F, mask = _interpret(out, len(x_a))
    except (TypeError, ValueError) as exc:  # a user's function returning something else
        return Estimate(name, None, None, seconds, f"returned {_describe(out)}, not F or (F, inlier_mask) ({exc})")
    if F is None or not is_valid(F):
        return Estimate(name, None, None, seconds, "returned no valid 3x3 F (None, NaN or all zero)")
    return Estimate(name, F, mask, seconds)


def _interpret(out: Any, n_matches: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(F (3, 3) float64 or None, inlier mask (M,) bool or None) of what an estimator returned."""
    if isinstance(out, tuple):
        if len(out) != 2:
            raise ValueError(f"a tuple of {len(out)} items")
        F, mask = out
    else:
        F, mask = out, None
    if F is None:
        return None, None
    F = np.asarray(F, dtype=np.float64)
    if F.shape != (3, 3):
        raise ValueError(f"shape {F.shape}")
    if mask is not None:
        mask = np.asarray(mask).reshape(-1)
        mask = mask.astype(bool) if mask.shape[0] == n_matches and mask.dtype.kind in "biuf" else None
    return F, mask


def _describe(out: Any) -> str:
    text = " ".join(repr(out).split())
    return f"{type(out).__name__} {text[:40]}{'...' if len(text) > 40 else ''}"
