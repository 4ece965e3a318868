"""Baselines that estimate nothing from the pair's content.

- ``ahead``: straight-ahead motion without rotation, F = K_b^-T [z]x K_a^-1, from the cameras alone;
- a constant F, the mean ground-truth F of some selection of pairs (:func:`mean_fundamental`): of the
  evaluated pairs themselves it is an oracle (``oracle-mean``: it has seen the test labels); of other
  sequences (``mean:SEL``) it is a fair prior.
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
