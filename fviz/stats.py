"""Statistics under every layer (numpy only): Wilcoxon's signed-rank test of paired differences, which compare,
the held-out reports and the ground-truth bias (fviz.diagnose) share; :func:`number`, a JSON figure as a float;
:func:`fmt`, a figure in a table cell."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

EXACT_MAX_N = 50  # Wilcoxon: exact distribution up to this many non-zero differences


@dataclass(frozen=True)
class Wilcoxon:
    """Wilcoxon's signed-rank test of paired differences: ``n`` non-zero differences (zeros are dropped), the
    rank sums of the positive and negative ones, the two-sided p-value and how it was computed
    (``exact``, ``normal``, or ``none`` when no difference is non-zero: p is NaN)."""

    n: int
    w_plus: float
    w_minus: float
    p: float
    method: str


def signed_ranks(d) -> tuple[np.ndarray, np.ndarray]:
    """(ranks of |d| with ties averaged, signs) of the non-zero differences. (N,) -> (n,), (n,)."""
    d = np.asarray(d, np.float64)
    d = d[np.isfinite(d) & (d != 0)]
    order = np.argsort(np.abs(d), kind="stable")
    a = np.abs(d)[order]
    ranks = np.empty(len(d))
    i = 0
    while i < len(a):  # runs of equal |d| share their mean rank
        j = i
        while j + 1 < len(a) and a[j + 1] == a[i]:
            j += 1
        ranks[order[i: j + 1]] = (i + j) / 2 + 1
        i = j + 1
    return ranks, np.sign(d)


def wilcoxon_signed_rank(d) -> Wilcoxon:
    """Two-sided Wilcoxon signed-rank test of the differences ``d`` (N,): exact (every sign flip of the
    ranks, ties averaged: the doubled ranks are integers) up to EXACT_MAX_N non-zero differences, above
    that the normal approximation with the tie correction and a continuity correction."""
    ranks, signs = signed_ranks(d)
    n = len(ranks)
    w_plus, w_minus = float(ranks[signs > 0].sum()), float(ranks[signs < 0].sum())
    if n == 0:
        return Wilcoxon(0, 0.0, 0.0, math.nan, "none")
    if n <= EXACT_MAX_N:
        doubled = np.round(2 * ranks).astype(int)
        counts = np.zeros(int(doubled.sum()) + 1)  # counts[s]: sign assignments whose doubled W+ is s
        counts[0] = 1.0
        for r in doubled:
            counts[r:] += counts[:-r].copy()  # r >= 2: each match either adds its rank or not
        prob = counts / counts.sum()
        w = int(round(2 * w_plus))
        p = 2 * min(prob[: w + 1].sum(), prob[w:].sum())
        return Wilcoxon(n, w_plus, w_minus, float(min(1.0, p)), "exact")
    _, tied = np.unique(ranks, return_counts=True)
    mean = n * (n + 1) / 4
    sd = math.sqrt(n * (n + 1) * (2 * n + 1) / 24 - float((tied**3 - tied).sum()) / 48)
    z = (abs(w_plus - mean) - 0.5) / sd if sd > 0 else 0.0
    return Wilcoxon(n, w_plus, w_minus, float(min(1.0, math.erfc(max(z, 0.0) / math.sqrt(2)))), "normal")


def number(v) -> float:
    """A JSON number as a float, NaN for null (None): how fviz reads the figures it wrote."""
    return float("nan") if v is None else float(v)


def fmt(v: float | None, digits: int = 3, missing: str = "–") -> str:
    """``v`` to ``digits`` significant digits; ``missing`` for None, NaN and infinities (a cell without a value)."""
    return missing if v is None or not math.isfinite(v) else f"{v:.{digits}g}"
