"""Findings per estimator over a run (printed above triage's pairs):

- ``ignores-input``: over IGNORES_MIN_PAIRS or more pairs, the estimator's epipole (viewing ray K_a^-1 e_a) or
  recovered rotation cannot be told from one that ignores the images: the slope of its pair-to-pair offsets on
  the ground truth's (:func:`tracking_slope`; 1 follows, 0 ignores, whatever its own jitter) has an
  IGNORES_CONFIDENCE interval (a paired bootstrap over the pairs) reaching below IGNORES_FRACTION; a quantity the
  ground truth itself varies by less than MIN_GT_SPREAD_DEG is not judged (a steady turn, rectified stereo);
- ``worse-than-baseline``: its median over pairs of ``sed_median`` (failures count as infinite) is above
  that of ``ahead`` (straight-ahead motion from the cameras alone), measured on every pair by eval.

The rules in full: :mod:`fviz.triage`'s docstring."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fviz.estimators.registry import AHEAD
from fviz.evaluate import GT_NAME
from fviz.stats import number

IGNORES_FRACTION = 0.1
IGNORES_CONFIDENCE, IGNORES_BOOTSTRAP = 0.95, 200  # the tracking slope's interval (paired bootstrap over the pairs)
IGNORES_MIN_PAIRS = 5
MIN_GT_SPREAD_DEG = 0.01  # a quantity the ground truth varies less than this is not judged


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def direction_spread_deg(rays: np.ndarray) -> float:
    """Median angle (deg) of sign-free directions (N, 3) to their centre (the element-wise median of the
    sign-aligned unit vectors: one wild estimate does not move it)."""
    rays = _unit_rows(np.asarray(rays, np.float64))
    rays = rays * np.where(rays @ rays[0] < 0, -1.0, 1.0)[:, None]
    centre = np.median(rays, axis=0)
    centre /= np.linalg.norm(centre)
    return float(np.median(np.degrees(np.arccos(np.clip(np.abs(rays @ centre), 0.0, 1.0)))))


def rotation_spread_deg(Rs: np.ndarray) -> float:
    """Median angle (deg) of rotations (N, 3, 3) to their centre (the element-wise median projected onto
    the rotations)."""
    from fviz.geometry import nearest_rotation, rotation_error_deg

    centre = nearest_rotation(np.median(Rs, axis=0))
    return float(np.median(rotation_error_deg(Rs, centre)))


def _offsets(x: np.ndarray, rotations: bool, ref: np.ndarray) -> np.ndarray:
    """Per pair, how far each of ``x`` sits from their centre: rays (N, 3) -> (N, 3) unit-vector offsets from the
    normalized median (signs aligned with ``ref``, a ray), rotations (N, 3, 3) -> (N, 3) rotation vectors of R C^T
    (small-angle)."""
    if rotations:
        from fviz.geometry import nearest_rotation

        D = x @ nearest_rotation(np.median(x, axis=0)).T
        return 0.5 * np.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0], D[:, 1, 0] - D[:, 0, 1]], axis=1)
    x = _unit_rows(x)
    x = x * np.where(x @ ref < 0, -1.0, 1.0)[:, None]
    centre = np.median(x, axis=0)
    return x - centre / np.linalg.norm(centre)


def tracking_slope(est, gt, rotations: bool, n: int = IGNORES_BOOTSTRAP, seed: int = 0) -> tuple[float, float, float]:
    """How much an estimate moves *with* the ground truth from pair to pair: the least-squares slope of its
    offsets on the truth's (1: follows it, 0: ignores it, whatever its own jitter) and the IGNORES_CONFIDENCE
    interval of that slope by a paired bootstrap over the pairs (seeded: the same run, the same interval).
    ``est``, ``gt``: per pair rays (N, 3) or rotations (N, 3, 3). -> (slope, low, high)."""
    est, gt = np.asarray(est, np.float64), np.asarray(gt, np.float64)
    e, g = _offsets(est, rotations, gt[0]), _offsets(gt, rotations, gt[0])  # rays: one sign for both
    dot, sq = np.einsum("ni,ni->n", e, g), np.einsum("ni,ni->n", g, g)
    idx = np.random.default_rng(seed).integers(0, len(e), size=(n, len(e)))
    slopes = dot[idx].sum(1) / np.maximum(sq[idx].sum(1), 1e-300)
    tail = 50.0 * (1.0 - IGNORES_CONFIDENCE)
    lo, hi = np.percentile(slopes, [tail, 100.0 - tail])
    return float(dot.sum() / max(sq.sum(), 1e-300)), float(lo), float(hi)


@dataclass
class Finding:
    """What triage says about one estimator over the run."""

    name: str
    pairs: int
    sed_median: float  # median over pairs of the per-pair sed_median (failures: infinite)
    pose_err_median: float
    epipole_spread: float  # deg, and the ground truth's over the same pairs
    gt_epipole_spread: float
    rotation_spread: float
    gt_rotation_spread: float
    flags: list[tuple[str, str]] = field(default_factory=list)


def _epipole_ray(F: np.ndarray, K: np.ndarray) -> np.ndarray:
    from fviz.geometry import epipoles

    return np.linalg.solve(K, epipoles(F)[0])


def estimator_findings(records, names: list[str]) -> list[Finding]:
    """``ignores-input`` and ``worse-than-baseline`` of each estimator (see the module doc)."""
    per: dict[str, dict[str, list]] = {n: {"ray": [], "gt_ray": [], "R": [], "gt_R": [], "sed": [], "pose": []}
                                       for n in names}
    ahead_sed: list[float] = []
    for rec in records:
        res = rec.get("result")
        if rec["error"] or not res:
            for n in names:
                per[n]["sed"].append(math.inf)
                per[n]["pose"].append(math.inf)
            continue
        rows = {e["name"]: e for e in res["estimators"]}
        K_a, F_gt = np.array(res["pair"]["K_a"]), np.array(res["F_gt"])
        gt = rows.get(GT_NAME, {})
        ahead_sed.append(number((rec.get("diagnostics") or {}).get("ahead_sed_median")))
        for n in names:
            e, d = rows.get(n), per[n]
            ok = e is not None and not e["error"]
            d["sed"].append(number(e["metrics"].get("sed_median")) if ok else math.inf)
            d["pose"].append(number(e["metrics"].get("pose_err_deg")) if ok else math.inf)
            if ok and e.get("R") is not None and gt.get("R") is not None:
                d["ray"].append(_epipole_ray(np.array(e["F"]), K_a))
                d["gt_ray"].append(_epipole_ray(F_gt, K_a))
                d["R"].append(e["R"])
                d["gt_R"].append(gt["R"])
    finite_ahead = [v for v in ahead_sed if math.isfinite(v)]
    ahead_median = float(np.median(finite_ahead)) if finite_ahead else math.nan
    out = []
    for n in names:
        d = per[n]
        sed = np.nan_to_num(np.array(d["sed"], float), nan=math.inf)
        pose = np.nan_to_num(np.array(d["pose"], float), nan=math.inf)
        k = len(d["R"])
        spreads = [math.nan] * 4
        if k >= 2:
            spreads = [direction_spread_deg(np.array(d["ray"])), direction_spread_deg(np.array(d["gt_ray"])),
                       rotation_spread_deg(np.array(d["R"])), rotation_spread_deg(np.array(d["gt_R"]))]
        f = Finding(n, len(sed), float(np.median(sed)) if len(sed) else math.nan,
                    float(np.median(pose)) if len(pose) else math.nan, *spreads)
        judged = [(what, est, gt, tracking_slope(d[key], d[f"gt_{key}"], key == "R"))
                  for what, key, est, gt in (("epipole", "ray", f.epipole_spread, f.gt_epipole_spread),
                                             ("rotation", "R", f.rotation_spread, f.gt_rotation_spread))
                  if k >= IGNORES_MIN_PAIRS and gt >= MIN_GT_SPREAD_DEG]
        low = [(what, est, gt, slope) for what, est, gt, slope in judged if slope[1] < IGNORES_FRACTION]
        if low:
            f.flags.append(("ignores-input", " and ".join(
                f"{what} follows the ground truth with slope {b:.2f} ({IGNORES_CONFIDENCE:.0%} interval {lo:.2f} to "
                f"{hi:.2f}; spread {est:.3g} deg, the truth's {gt:.3g})" for what, est, gt, (b, lo, hi) in low)
                + f" over {k} pairs: not told apart from ignoring its input (slope below {IGNORES_FRACTION:g})"))
        if n != AHEAD and math.isfinite(ahead_median) and f.sed_median > ahead_median:
            f.flags.append(("worse-than-baseline", f"median SED {f.sed_median:.3g} px > {ahead_median:.3g} px of "
                            f"`{AHEAD}` (straight-ahead motion from the cameras alone)"))
        out.append(f)
    return out
