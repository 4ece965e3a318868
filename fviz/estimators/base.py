"""What an estimator is: a callable from a pair and its matches to an F.

    estimate(pair, x_a, x_b) -> F  or  (F, inlier_mask)

pair: :class:`fviz.data.Pair`; x_a, x_b: (M, 2) matched pixel coordinates (x_b^T F x_a = 0);
F: (3, 3); inlier_mask: (M,) bool, or None when the method has no notion of inliers.
Correspondence-free (deep) estimators read ``pair.image_a`` / ``pair.image_b`` and ignore the matches.
The runner (:func:`fviz.estimators.run_estimator`) times the call and turns exceptions and
invalid (NaN, zero) matrices into an :class:`Estimate` with ``error`` set.

Every estimator is isolated the same way on every path (inspect, eval with any number of workers,
triage): it gets its own copies of the pair and the matches (changing them in place harms no other
estimator), what it prints goes to stderr (``--json`` on stdout stays clean), anything it raises
(SystemExit and KeyboardInterrupt included) is its failure on that pair, and past ``timeout`` seconds
(``--estimator-timeout``) it fails the pair while the run goes on; its thread is then left behind,
daemonic, and ends with the process.
"""

from __future__ import annotations

import contextlib
import copy
import sys
import threading
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


DEFAULT_TIMEOUT_S = 600.0


def missing_K(name: str, fn: EstimateFn, pair) -> str | None:
    """Why estimator ``name`` cannot run on ``pair``: it needs the cameras' intrinsics (``fn.needs_K``, e.g.
    ``poselib-E``, ``ahead``) and the pair has none; None when it can."""
    if not getattr(fn, "needs_K", False) or pair.has_K:
        return None
    return (f"{name} needs the cameras' intrinsics K, which this pair lacks: give --K (or --K-a and --K-b), "
            "or use a source with intrinsics (KITTI, a pairs file with K, a COLMAP model)")


def _isolated_call(fn: EstimateFn, args: tuple, timeout: float) -> tuple[str, Any]:
    """("ok", what fn returned), ("raised", the exception) or ("timeout", None): fn runs in a thread of
    its own (torch's grad mode carried over), its stdout sent to stderr. A Ctrl-C reaches the caller."""
    box: dict[str, Any] = {}
    torch = sys.modules.get("torch")
    grad = torch.is_grad_enabled() if torch is not None else None

    def call() -> None:
        try:
            if grad is not None:
                torch.set_grad_enabled(grad)
            box["ok"] = fn(*args)
        except BaseException as exc:  # SystemExit, KeyboardInterrupt: the estimator's failure, not the run's
            box["raised"] = exc

    thread = threading.Thread(target=call, daemon=True, name="fviz-estimator")
    with contextlib.redirect_stdout(sys.stderr):
        thread.start()
        thread.join(timeout)
    if thread.is_alive():
        return "timeout", None
    return next(iter(box.items()))


def run_estimator(name: str, fn: EstimateFn, pair, x_a: np.ndarray, x_b: np.ndarray,
                  timeout: float | None = None) -> Estimate:
    """Call one estimator, isolated (see the module docstring), never raising: failures come back as
    ``Estimate.error``."""
    from fviz.geometry import is_valid

    timeout = DEFAULT_TIMEOUT_S if timeout is None else timeout
    if (why := missing_K(name, fn, pair)) is not None:
        return Estimate(name, None, None, 0.0, why)
    args = (copy.deepcopy(pair), np.array(x_a, copy=True), np.array(x_b, copy=True))
    t0 = time.perf_counter()
    kind, out = _isolated_call(fn, args, timeout)
    seconds = time.perf_counter() - t0
    if kind == "timeout":
        return Estimate(name, None, None, seconds, f"timed out after {timeout:g} s (--estimator-timeout)")
    if kind == "raised":
        text = f"called exit({out.code!r})" if isinstance(out, SystemExit) else str(out) or "raised with no message"
        what = f"{type(out).__name__}: {text}"
        if os.environ.get("FVIZ_DEBUG"):  # fviz --debug: where it raised, for the author of the estimator
            import traceback

            what += "\n" + "".join(traceback.format_exception(out)).rstrip()
        return Estimate(name, None, None, seconds, what)
    try:
        F, mask = _interpret(out, len(x_a))
    except Exception as exc:  # a user's function returning something else (or an array-like that will not convert)
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
    F = _as_array(F)
    if F.dtype.kind == "c":
        raise ValueError("a complex F: return its real part yourself if that is what you mean")
    F = F.astype(np.float64)
    if F.shape != (3, 3):
        raise ValueError(f"shape {F.shape}")
    if mask is not None:
        mask = _as_array(mask).reshape(-1)
        if mask.shape[0] != n_matches:
            raise ValueError(f"an inlier mask of {mask.shape[0]} entries for {n_matches} matches")
        if mask.dtype.kind not in "biuf":
            raise ValueError(f"an inlier mask of {mask.dtype} values")
        mask = mask.astype(bool)
    return F, mask


def _as_array(x: Any) -> np.ndarray:
    """A numpy array of what an estimator returned: torch tensors detached and moved to the CPU first."""
    if hasattr(x, "detach") and hasattr(x, "cpu"):  # a torch tensor, possibly requiring grad or on a GPU
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def _describe(out: Any) -> str:
    text = " ".join(repr(out).split())
    return f"{type(out).__name__} {text[:40]}{'...' if len(text) > 40 else ''}"
