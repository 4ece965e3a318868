"""A run's plots: the metric series and motion tracks over its pairs (their styles, values and y ranges), the
legend, and the cumulative error curves with the standard figures read off them."""

from __future__ import annotations

import math
from typing import Iterable, Sequence

import numpy as np

from fviz.evaluate import PairResult
from fviz.geometry import (
    AUC_THRESHOLDS_DEG, NSGD_RECALL_THRESHOLD, describe_epipole, epipoles, pose_auc, rotation_angle_deg,
)
from fviz.record import layout as L
from fviz.record.charts import CURVE_GAP, CURVE_H, CURVE_W
from fviz.record.plots import LOG_FLOOR, TRACK_FLOOR, log_values, series_range
from fviz.record.marks import Colors, names_of, rgb


# The series' values (what readers read) and, for the errors, the log10 their plots draw (layout.metric_plot).
VALUE_PATHS = tuple([L.metric(k) for k in L.SERIES_METRICS] + [L.motion(k) for k, _ in L.MOTION_TRACKS])
SERIES_PATHS = VALUE_PATHS + tuple(L.metric_plot(k) for k in L.SERIES_METRICS if k in L.LOG_METRICS)
POINT_PATHS = frozenset({L.motion("epipole_dir_deg")})  # sporadic samples (the pairs whose epipole is at infinity)
MARKER_SIZE = 3.0


def log_static(rec, estimator_names: list[str], series: bool = False, legend: bool = True, points: bool = False,
               ranges: dict | None = None, motion: bool = True) -> None:
    """Once per recording: the residual legend (``legend``: when it holds matches) and, for runs (``series``),
    the names, colours and marks of the metric series and (``motion``) the motion tracks (:func:`series_styles`),
    and their legend (``layout.LEGEND``)."""
    if legend:
        rec.log("/", L.annotation_context(), static=True)
    if series:
        colors = L.estimator_colors(estimator_names)
        for path in SERIES_PATHS if motion else [p for p in SERIES_PATHS if not p.startswith("motion/")]:
            cut = (ranges or {}).get(path) or (0, 0, {})
            rec.log(path, *series_styles(colors, points or path in POINT_PATHS, cut[2]), static=True)
        log_legend(rec, colors)


def series_styles(colors: Colors, points: bool = False, cut: Iterable[str] = ()) -> list:
    """How a plot draws its series (one per F, named and in its colour): lines joining consecutive pairs, or
    points (``points``: series over triage's ranks, where neighbours are unrelated pairs; a series ``cut`` off
    the plot's range: its off-scale swings would streak across the plot). -> archetypes to log on the series."""
    import rerun as rr

    names, rgbs = list(colors), [rgb(c) for c in colors.values()]
    dots = [points or n in set(cut) for n in names]
    out = [] if all(dots) else [rr.SeriesLines(names=names, colors=rgbs, visible_series=[not d for d in dots])]
    if any(dots):
        out.append(rr.SeriesPoints(names=names, colors=rgbs, visible_series=dots, marker_sizes=[MARKER_SIZE] * len(names)))
    return out


def log_legend(rec, colors: Colors, path: str = L.LEGEND, origin=(0.0, 0.0), pitch: float = 24.0,
               labels: dict[str, str] | None = None) -> None:
    """One row per F: a bar in its colour and its name beside it (or ``labels[name]``, centred as far right as
    it is long, ~7 units a character), labels white on Rerun's grey boxes, their points 0.4 rows up (Rerun
    draws a label below its point), drawn in 2D on the charts' dark background. -> rows of ``pitch`` units
    from ``origin``."""
    import rerun as rr

    x0, y0 = origin
    rows = list(colors.items())
    bars = [[(x0, y0 + i * pitch), (x0 + 40.0, y0 + i * pitch)] for i in range(len(rows))]
    text = [(labels or {}).get(n, "ground truth" if n == L.GT else n) for n, _ in rows]
    xs = [x0 + 120.0 if labels is None else x0 + 60.0 + 3.6 * len(t) for t in text]
    rec.log(path, rr.LineStrips2D(bars, colors=[rgb(c) for _, c in rows], radii=pitch / 4),
            rr.Points2D([(x, y0 + (i - 0.4) * pitch) for i, x in enumerate(xs)], radii=0.1, colors=[(255, 255, 255)],
                        labels=text, show_labels=True), static=True)


def motion_values(result: PairResult) -> dict[str, list[float]]:
    """{track: one value per F} (``motion/*`` in :mod:`fviz.record.layout`): the image-a epipole, and where
    the estimator's pose is known (``R``, ``t`` of its result) the rotation angle and the translation
    direction with the ground truth's sign. NaN where unknown."""
    w, h = result.pair.get("size_a", (0, 0))  # a pair that failed as a whole has no size, and no F
    gt = result.get(L.GT)
    t_gt = None if gt is None or getattr(gt, "t", None) is None else np.asarray(gt.t, float)
    out: dict[str, list[float]] = {k: [] for k, _ in L.MOTION_TRACKS}
    for r in result.estimators:
        v = dict.fromkeys(out, np.nan)
        if r.F is not None:
            ep = describe_epipole(epipoles(r.F)[0], w, h)
            if ep.point is None or np.abs(ep.point - (w / 2, h / 2)).max() > 50 * max(w, h):
                v["epipole_dir_deg"] = float(np.degrees(np.arctan2(ep.direction[1], ep.direction[0])))
            else:
                v["epipole_x"], v["epipole_y"] = map(float, ep.point)
        R, t = getattr(r, "R", None), getattr(r, "t", None)
        if R is not None:
            v["rotation_deg"] = float(rotation_angle_deg(R))
        if t is not None and np.linalg.norm(t) > 0:
            t = np.asarray(t, float) / np.linalg.norm(t)
            if t_gt is not None and t @ t_gt < 0:
                t = -t
            v["t_x"], v["t_y"], v["t_z"] = map(float, t)
        for k in out:
            out[k].append(v[k])
    return out


def log_series(rec, result: PairResult, motion: bool = True) -> None:
    """The metric series (and with ``motion`` the motion tracks) of the pair at the current time (runs of many
    pairs): one value per F, in the order of the series names (NaN for a failed estimator); an error metric's
    log10 beside it, for its plot (layout.metric_plot)."""
    import rerun as rr

    for key in L.SERIES_METRICS:
        values = [r.metrics.get(key, np.nan) if not r.error else np.nan for r in result.estimators]
        rec.log(L.metric(key), rr.Scalars(values))
        if key in L.LOG_METRICS:
            rec.log(L.metric_plot(key), rr.Scalars(log_values(values)))
    for key, values in (motion_values(result).items() if motion else ()):
        rec.log(L.motion(key), rr.Scalars(values))


def series_values(results: Iterable[PairResult]) -> dict[str, dict[str, list[float]]]:
    """{series path: {F: its value on each pair (NaN where unknown)}} of the runs' plots (metrics and motion),
    as :func:`log_series` logs them; also ``metrics/{key}`` of the cumulative curves' metrics (CURVE_METRICS)."""
    out: dict[str, dict[str, list[float]]] = {}
    keys = dict.fromkeys([*L.SERIES_METRICS, *(k for k, *_ in CURVE_METRICS)])
    for result in results:
        names = names_of(result)
        per = {L.metric(k): [np.nan if r.error else r.metrics.get(k, np.nan) for r in result.estimators] for k in keys}
        per.update({L.motion(k): v for k, v in motion_values(result).items()})
        for path, values in per.items():
            for n, v in zip(names, values):
                out.setdefault(path, {}).setdefault(n, []).append(float(v))
    return out


def ranges_of_values(values: dict[str, dict[str, Sequence[float]]]) -> dict[str, tuple | None]:
    """{plotted path: its plot's y range (layout.series_range) or None} of :func:`series_values` (or the values
    the recording holds): an error metric's on its log10 (every value above LOG_FLOOR), the other metrics'
    from 0 with every value, the motion tracks' leaving a wild series out."""
    out = {}
    for path, per in values.items():
        key = path.removeprefix("metrics/")
        if path.startswith("motion/"):
            out[path] = series_range(per, TRACK_FLOOR.get(path.removeprefix("motion/"), 1e-3))
        elif key in L.LOG_METRICS:
            logs = {n: log_values(np.where(np.asarray(v, float) > LOG_FLOOR, v, np.nan)) for n, v in per.items()}
            out[L.metric_plot(key)] = series_range(logs, 0.1, cut=False)
        elif key in L.SERIES_METRICS:
            out[path] = series_range(per, zero=True, cut=False)
    return out


def series_ranges_of(results: Iterable[PairResult]) -> dict[str, tuple | None]:
    return ranges_of_values(series_values(results))


# The cumulative error curves of a run: (metric, title, thresholds, log x axis).
CURVE_METRICS = (
    ("pose_err_deg", "pose error (deg)", np.geomspace(0.01, 30.0, 71), True),
    ("sed_median", "median SED (px)", np.geomspace(0.01, 10.0, 61), True),
    ("nsgd", "NSGD (FM-Bench)", np.geomspace(1e-3, 1.0, 61), True),
)
# The standard figures' thresholds, marked on their curves: (x, label)
CURVE_MARKS = {"pose_err_deg": [(t, f"{t:g}°") for t in AUC_THRESHOLDS_DEG],
               "nsgd": [(NSGD_RECALL_THRESHOLD, f"{NSGD_RECALL_THRESHOLD:g}")]}


def cumulative_curve(values: Sequence[float], thresholds: np.ndarray) -> np.ndarray:
    """Share of the pairs whose value is below each threshold; NaN (a failure) never is. (P,), (T,) -> (T,)."""
    v = np.nan_to_num(np.asarray(values, float), nan=np.inf)
    return (v[:, None] < np.asarray(thresholds, float)[None]).mean(axis=0) if len(v) else np.zeros(len(thresholds))


def curve_figures(per_pair: dict[str, dict[str, Sequence[float]]], name: str) -> str:
    """The standard figures read off ``name``'s curves (those it has): "AUC@5/10/20° 0.74/0.87/0.94, NSGD recall 100%"."""
    out = []
    if (pose := per_pair.get("pose_err_deg", {}).get(name)) is not None:
        slash = "/".join(f"{t:g}" for t in AUC_THRESHOLDS_DEG)
        out.append(f"AUC@{slash}° " + "/".join(f"{a:.2f}" for a in pose_auc(pose)))
    if (nsgd := per_pair.get("nsgd", {}).get(name)) is not None:
        out.append(f"NSGD recall {cumulative_curve(nsgd, [NSGD_RECALL_THRESHOLD])[0]:.0%}")
    return ", ".join(out)


def log_curves(rec, per_pair: dict[str, dict[str, Sequence[float]]], colors: Colors) -> None:
    """``curves/{metric}``: per metric of CURVE_METRICS a panel with one curve per F in its colour (share of the
    pairs below x), axes and ticks, the standard figures' thresholds marked (CURVE_MARKS), and the curves'
    values (AnyValues: ``thresholds``, ``estimators``, ``recall`` row-major F x threshold) for readers; below, the
    legend with each F's figures (AUC, NSGD recall). ``per_pair``: {metric: {F: value per pair, NaN failed}}."""
    import rerun as rr

    white, grey = (200, 200, 200), (150, 150, 150)
    for i, (key, title, thresholds, log_x) in enumerate(CURVE_METRICS):
        per = {n: v for n, v in per_pair.get(key, {}).items() if n != L.GT}
        if not per:
            continue
        x0 = i * (CURVE_W + CURVE_GAP)
        u = np.log10(thresholds) if log_x else thresholds

        def screen_x(t: float) -> float:
            return x0 + CURVE_W * ((np.log10(t) if log_x else t) - u[0]) / (u[-1] - u[0])

        recall = {n: cumulative_curve(v, thresholds) for n, v in per.items()}
        strips = [np.stack([screen_x(thresholds), CURVE_H * (1 - r)], -1) for r in recall.values()]
        lo, hi = float(thresholds[0]), float(thresholds[-1])
        ticks_x = ([10.0**k for k in range(math.ceil(math.log10(lo) - 1e-9), math.floor(math.log10(hi) + 1e-9) + 1)]
                   if log_x else list(np.linspace(lo, hi, 5)))
        axes = [[(x0, 0.0), (x0, CURVE_H), (x0 + CURVE_W, CURVE_H)]]
        tick_pos, tick_labels = [], []
        for t in ticks_x:
            axes.append([(screen_x(t), CURVE_H), (screen_x(t), CURVE_H + 6)])
            tick_pos.append((screen_x(t), CURVE_H + 22))
            tick_labels.append(f"{t:g}")
        for y in (0.0, 0.5, 1.0):
            axes.append([(x0 - 6, CURVE_H * (1 - y)), (x0, CURVE_H * (1 - y))])
            tick_pos.append((x0 - 30, CURVE_H * (1 - y)))
            tick_labels.append(f"{y:.0%}")
        marks = [[(screen_x(t), 0.0), (screen_x(t), CURVE_H)] for t, _ in CURVE_MARKS.get(key, ())]
        for t, label in CURVE_MARKS.get(key, ()):  # above the panel, below its title
            tick_pos.append((screen_x(t), -24.0))
            tick_labels.append(label)
        tick_pos.append((x0 + CURVE_W / 2, -52.0))
        tick_labels.append(f"share of the pairs with {title} < x" + (" (log x)" if log_x else ""))
        rec.log(f"{L.CURVES}/{key}",
                rr.LineStrips2D(strips + axes + marks, colors=[rgb(colors[n]) for n in recall] + [white] * len(axes) + [grey] * len(marks),
                                radii=[2.0] * len(strips) + [0.8] * len(axes) + [0.6] * len(marks)),
                rr.Points2D(tick_pos, radii=0.1, colors=[(255, 255, 255)], labels=tick_labels, show_labels=True),
                rr.AnyValues(thresholds=np.asarray(thresholds, float), estimators=list(recall),
                             recall=np.concatenate(list(recall.values()))), static=True)
    shown = {n: c for n, c in colors.items() if n != L.GT}
    figures = {n: curve_figures(per_pair, n) for n in shown}
    log_legend(rec, shown, f"{L.CURVES}/legend", (0.0, CURVE_H + 70.0),
               labels={n: f"{n}: {f}" if f else n for n, f in figures.items()})
