"""Threshold sweeps: a robust estimator at a given threshold (``magsac@0.5``) and the per-pair oracle over a
grid (``magsac@oracle``, or ``magsac@oracle=0.5,1,2``).

``--threshold sweep`` (the grid SWEEP_GRID_PX) or ``--threshold 0.5,1,2`` expands every robust estimator of
the run into one spec per threshold plus its oracle (:func:`sweep_specs`). The oracle runs the estimator at
each threshold of the grid and keeps, per pair, the F with the lowest median symmetric epipolar distance
on the matches within ORACLE_GT_PX of the ground truth's lines: it is chosen with the labels, like
glue-factory's ``ransac_th=-1``, so reports mark it *oracle*. Display names: ``magsac-th0.5``, ``magsac-th-oracle``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fviz.errors import FvizError

SWEEP_GRID_PX = (0.25, 0.5, 1.0, 2.0, 4.0)
ORACLE = "oracle"
ORACLE_SUFFIX = "-th-oracle"
ORACLE_GT_PX = 2.0  # the paper's evaluation threshold (fviz.evaluate.EVAL_THRESHOLD_PX)


def sweepable() -> frozenset[str]:
    """The estimators whose result depends on a threshold (7point, 8point and lmeds have none)."""
    from fviz.estimators.classical import USAC_FLAGS
    from fviz.estimators.external import METHODS

    return frozenset({"ransac", "magsac", *USAC_FLAGS, *METHODS})


def split_threshold(spec: str) -> tuple[str, str | None]:
    """``magsac@0.5`` -> (magsac, "0.5"); a spec without a threshold -> (spec, None)."""
    base, sep, th = spec.partition("@")
    return (base, th) if sep and base in sweepable() else (spec, None)


def parse_grid(text: str, flag: str) -> tuple[float, ...]:
    """``0.5,1,2`` -> (0.5, 1.0, 2.0): positive finite numbers, or a one-line error naming ``flag``."""
    try:
        grid = tuple(float(v) for v in text.split(","))
    except ValueError:
        grid = ()
    if not grid or not all(np.isfinite(v) and v > 0 for v in grid):
        raise FvizError(f"{flag} {text!r}: expected numbers > 0 (px), comma separated")
    return grid


def threshold_name(base_name: str, th: str) -> str:
    """The display name of ``base@th``."""
    return base_name + (ORACLE_SUFFIX if th.startswith(ORACLE) else f"-th{th}")


def parse_threshold(text: str) -> tuple[float, tuple[float, ...]]:
    """``--threshold``: ``1.5`` -> (1.5, ()); ``sweep`` -> (1.0, SWEEP_GRID_PX); ``0.5,1,2`` -> (1.0, that grid).
    The first value is the threshold of estimators left out of a sweep (and of inlier masks fviz computes)."""
    if text.strip() == "sweep":
        return 1.0, SWEEP_GRID_PX
    grid = parse_grid(text, "--threshold")
    return (grid[0], ()) if len(grid) == 1 else (1.0, grid)


def sweep_specs(specs, grid: tuple[float, ...]) -> tuple[str, ...]:
    """Each sweepable spec without a threshold -> one spec per threshold of ``grid`` and its oracle."""
    oracle = ORACLE if tuple(grid) == SWEEP_GRID_PX else f"{ORACLE}={','.join(f'{t:g}' for t in grid)}"
    out: list[str] = []
    for spec in specs:
        swept = spec in sweepable()
        out += [f"{spec}@{t:g}" for t in grid] + [f"{spec}@{oracle}"] if swept else [spec]
    return tuple(out)


def threshold_estimator(spec: str, cfg, resolve):
    """The estimator of ``base@th``: ``resolve(base, cfg)`` at that threshold, or the oracle over a grid."""
    base, th = split_threshold(spec)
    if not th.startswith(ORACLE):
        one = parse_grid(th, f"--estimator {spec}:")
        if len(one) != 1:
            raise FvizError(f"--estimator {spec}: one threshold per estimator (--threshold {th} sweeps them)")
        return resolve(base, replace(cfg, threshold=one[0]))
    rest = th[len(ORACLE):]
    if rest and not rest.startswith("="):
        raise FvizError(f"--estimator {spec}: write {base}@oracle or {base}@oracle=0.5,1,2")
    grid = parse_grid(rest[1:], f"--estimator {spec}:") if rest else SWEEP_GRID_PX
    return oracle_estimator([resolve(base, replace(cfg, threshold=t)) for t in grid])


def oracle_estimator(fns):
    """Of the estimates of ``fns`` (one per threshold), the one closest to the ground truth (see module doc)."""
    from fviz.geometry import is_valid, symmetric_epipolar_distance

    def estimate(pair, x_a, x_b):
        if getattr(pair, "F_gt", None) is None:
            raise FvizError("needs ground truth: the per-pair oracle keeps the threshold whose F is closest to it, "
                             "and this pair has none")
        near = symmetric_epipolar_distance(pair.F_gt, x_a, x_b) < ORACLE_GT_PX
        best, errors = None, []
        for fn in fns:
            try:
                out = fn(pair, x_a, x_b)
            except Exception as exc:  # one threshold failing leaves the others
                errors.append(str(exc))
                continue
            F, mask = out if isinstance(out, tuple) else (out, None)
            if F is None or not is_valid(F):
                continue
            err = float(np.median(symmetric_epipolar_distance(F, x_a[near], x_b[near]))) if near.any() else np.inf
            if best is None or err < best[0]:
                best = (err, F, mask)
        if best is None:
            raise ValueError("no threshold of the grid gave an F" + (f" ({errors[0]})" if errors else ""))
        return best[1], best[2]

    return estimate
