"""A run's plots (``metrics/{key}``, ``motion/{track}`` of :mod:`fviz.record.layout`): their titles, what an
error's plot draws (log10 of the values) and the y ranges that keep every series but a wild one readable."""

from __future__ import annotations

from typing import Sequence

import numpy as np

METRIC_TITLES = {
    "sed_median": "median SED (px)", "sed_mean": "mean SED (px)", "sampson_median": "median Sampson (px)",
    "sampson_mean": "mean Sampson (px)", "rot_err_deg": "rotation error (deg)",
    "trans_err_deg": "translation direction error (deg)", "pose_err_deg": "pose error (deg, max of rotation and translation)",
    "nsgd": "NSGD (FM-Bench, share of the diagonal)", "epipole_err_deg": "epipole error (deg)",
    "inlier_ratio": "inlier ratio (share of the matches)", "n_inliers": "inliers (matches)",
}


def metric_title(key: str) -> str:
    return METRIC_TITLES.get(key, key)


SERIES_CUT = 5.0  # a motion track whose 5-95 % band is this many times wider than the others' (median) is cut off
# Error metrics are plotted on log axes (Rerun's plots are linear: their log10 is logged beside the value, see
# fviz.record.layout.metric_plot), so that one range holds an estimator 100x worse beside the best; a value below
# LOG_FLOOR (the ground truth's zero errors) is plotted at it, below the axis.
LOG_METRICS = frozenset({"sed_median", "rot_err_deg", "trans_err_deg", "nsgd", "epipole_err_deg"})
LOG_FLOOR = 1e-4


def log_values(values: Sequence[float]) -> np.ndarray:
    """What a log metric's plot draws: log10 of the values, at least log10(LOG_FLOOR); NaN stays NaN."""
    with np.errstate(invalid="ignore"):
        return np.log10(np.maximum(np.asarray(values, float), LOG_FLOOR))


def series_range(values: dict[str, Sequence[float]], floor: float = 1e-3, zero: bool = False,
                 cut: bool = True) -> tuple[float, float, dict] | None:
    """The y range of one plot of a run. With ``cut`` (motion tracks), every series but a wild one is readable:
    the union of the series' 5-95 % bands, leaving out a series whose band is over SERIES_CUT times wider than
    the median band of the others (8-point's +-6000 px epipole swings beside ransac's +-30 px), padded by a
    quarter of the span; without (metrics), every value of every series, padded by a tenth. The padding is at
    least ``floor``; from 0 when ``zero``. -> (low, high, {series cut: its 5-95 % band}), None without a
    finite value.
    ``values``: {series name: its values over the pairs (NaN: none)}."""
    bands = {}
    for name, v in values.items():
        v = np.asarray(v, float)
        v = v[np.isfinite(v)]
        if len(v):
            bands[name] = (float(np.percentile(v, 5)), float(np.percentile(v, 95))) if cut else (float(v.min()), float(v.max()))
    if not bands:
        return None
    widths = {n: hi - lo for n, (lo, hi) in bands.items()}
    off = {}
    for n in bands if cut else ():
        others = [w for m, w in widths.items() if m != n and w > 0]
        if len(bands) > 2 and others and widths[n] > SERIES_CUT * max(float(np.median(others)), floor):
            off[n] = bands[n]
    kept = [bands[n] for n in bands if n not in off]
    lo, hi = min(b[0] for b in kept), max(b[1] for b in kept)
    if zero:
        lo = min(lo, 0.0)
    pad = max((0.25 if cut else 0.1) * (hi - lo), floor)
    return (lo if zero and lo == 0.0 else lo - pad), hi + pad, off


# Per track: the smallest padding of its range (px, deg, unit vector), so that a flat series stays a line.
TRACK_FLOOR = {"epipole_x": 2.0, "epipole_y": 2.0, "epipole_dir_deg": 0.05, "rotation_deg": 0.02}


def plot_title(key: str) -> str:
    return f"log10 of {metric_title(key)}" if key in LOG_METRICS else metric_title(key)


def _short(v: float) -> str:
    return f"{v / 1000:.3g}k" if abs(v) >= 1000 else f"{v:.3g}"


def off_scale_note(cut: dict[str, tuple[float, float]]) -> str:
    """A plot title's note on the series :func:`series_range` cut off: "; {name} off-scale {low} to {high}" each."""
    return "".join(f"; {n} off-scale {_short(a)} to {_short(b)}" for n, (a, b) in cut.items())
