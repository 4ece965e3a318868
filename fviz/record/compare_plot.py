"""compare.rrd: what ``fviz compare`` found, pair by pair, on one screen. Per pair of the run (x: its index) each
side's value of the metric in its colour (log y for errors, linear for ratios), the metric's fail threshold as a
line, a band behind every pair where only one side fails (in that side's colour, dimmed: a stretch of consecutive
pairs shows as one wide band), no value (an error) as a mark above the axes; beside it compare.md. Drawn in 2D
(Rerun's plots have no log axis) with the layout's entity paths (:mod:`fviz.record.layout`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fviz.record import layout as L

ERROR_Y = -16.0  # where a pair without a value is marked, above the axes
AXIS_COLOR = (200, 200, 200)
# compare.rrd (``fviz compare``): the metric of both sides per pair of the run, drawn in 2D (y down), and compare.md
COMPARE_PAIRS = "compare/pairs"
COMPARE_LEGEND = "compare/legend"
COMPARE_TEXT = "compare/text"
COMPARE_W, COMPARE_H = 1000.0, 360.0  # the plot's axes, in 2D units


def compare_blueprint(title: str):
    """compare.rrd's layout: the per-pair plot (its legend below it) beside compare.md."""
    import rerun.blueprint as rrb

    bounds = rrb.VisualBounds2D(x_range=[-90.0, COMPARE_W + 40.0], y_range=[-70.0, COMPARE_H + 150.0])
    plot = rrb.Spatial2DView(origin="compare", contents=[f"+ {COMPARE_PAIRS}/**", f"+ {COMPARE_LEGEND}"], name=title,
                             background=L.CHART_BACKGROUND, visual_bounds=bounds)
    text = rrb.TextDocumentView(origin=COMPARE_TEXT, name="compare.md")
    return rrb.Blueprint(rrb.Horizontal(plot, text, column_shares=[5, 2]), rrb.TimePanel(state="hidden"),
                         collapse_panels=True)


def y_scale(values: np.ndarray, threshold: float | None, log: bool):
    """(value -> y in the plot, tick values) over the finite values and the threshold: decades on a log axis."""
    v = values[np.isfinite(values) & ((values > 0) if log else True)]
    span = np.concatenate([v, [threshold] if threshold is not None else []])
    if log:
        lo, hi = (float(span.min()) / 1.5, float(span.max()) * 1.5) if len(span) else (0.1, 10.0)
        u0, u1 = math.log10(lo), math.log10(hi)
        ticks = [10.0**k for k in range(math.ceil(u0), math.floor(u1) + 1)]
        if len(ticks) < 3:  # less than three decades: the halves between them too
            ticks = sorted(ticks + [m * 10.0**k for k in range(math.floor(u0), math.ceil(u1) + 1) for m in (2.0, 5.0)
                                    if u0 <= math.log10(m) + k <= u1])
        to_y = lambda x: COMPARE_H * (u1 - np.log10(np.maximum(x, lo))) / (u1 - u0)  # noqa: E731
        return to_y, ticks
    lo, hi = (min(0.0, float(span.min())), max(1.0, float(span.max()))) if len(span) else (0.0, 1.0)
    return (lambda x: COMPARE_H * (hi - np.asarray(x, float)) / (hi - lo)), list(np.linspace(lo, hi, 5))


def _dim(color, k: float = 0.35) -> tuple[int, int, int]:
    """A colour blended into the chart's background (``k`` of it kept)."""
    return tuple(int(k * c + (1 - k) * b) for c, b in zip(color, L.CHART_BACKGROUND))


def log_compare_plot(rec, c, indices: dict[str, int]) -> None:
    """The plot of a :class:`fviz.compare.Comparison` at ``COMPARE_PAIRS`` (static), ``indices``: pair name
    -> its index in the run (pairs it lacks are placed after the others, in name order). Its values for readers:
    AnyValues ``pairs``, ``index``, ``a``, ``b`` (NaN: no value), ``only_a_fails``/``only_b_fails`` (0/1)."""
    import rerun as rr

    from fviz.record.marks import rgb
    from fviz.record.run_plots import log_legend
    from fviz.verdicts import HIGHER_IS_BETTER, fail_rule

    na, nb = c.names
    colors = L.estimator_colors([na, nb])
    names = sorted(c.values, key=lambda n: (indices.get(n, math.inf), n))
    index = np.array([indices.get(n, len(indices) + k) for k, n in enumerate(names)], float)
    a, b = (np.array([c.values[n][i] for n in names], float) for i in (0, 1))
    rule = fail_rule(c.metric, c.fail_threshold)
    threshold = rule.threshold if rule else None
    log = c.metric not in HIGHER_IS_BETTER and bool((np.concatenate([a, b]) > 0).any())
    to_y, ticks = y_scale(np.concatenate([a, b]), threshold, log)
    i0, i1 = (float(index.min()), float(index.max())) if len(index) else (0.0, 1.0)
    to_x = lambda i: COMPARE_W * ((i - i0) / (i1 - i0) if i1 > i0 else 0.5)  # noqa: E731
    step = COMPARE_W / max(i1 - i0, 1.0)  # one pair's width: neighbouring bands touch

    strips, strip_colors, strip_radii = [], [], []
    only = {na: set(c.only_a_fails), nb: set(c.only_b_fails)}
    # bands first (the points are drawn over them), each of thin vertical lines: one thick line's round caps would
    # bulge past the axes
    lines = max(1, round(step / 5.0))
    for side, failing in only.items():
        for n, i in zip(names, index):
            if n in failing:
                for x in to_x(i) + step * ((np.arange(lines) + 0.5) / lines - 0.5):
                    strips.append([(float(x), 2.0), (float(x), COMPARE_H - 2.0)])
                    strip_colors.append(_dim(colors[side]))
                    strip_radii.append(max(1.0, 0.5 * step / lines))
    axes = [[(0.0, 0.0), (0.0, COMPARE_H), (COMPARE_W, COMPARE_H)]]
    tick_pos, tick_labels = [], []
    for t in ticks:
        y = float(to_y(t))
        axes.append([(-6.0, y), (0.0, y)])
        tick_pos.append((-40.0, y - 10.0))
        tick_labels.append(f"{t:g}")
    for i in np.unique(np.round(np.linspace(i0, i1, min(7, len(names) or 1)))):
        axes.append([(to_x(i), COMPARE_H), (to_x(i), COMPARE_H + 6.0)])
        tick_pos.append((to_x(i), COMPARE_H + 10.0))
        tick_labels.append(f"#{i:g}")
    if threshold is not None:
        strips.append([(0.0, float(to_y(threshold))), (COMPARE_W, float(to_y(threshold)))])
        strip_colors.append(AXIS_COLOR)
        strip_radii.append(1.0)
        tick_pos.append((COMPARE_W - 120.0, float(to_y(threshold)) - 24.0))
        tick_labels.append(f"fails: {c.fails_label}")
    tick_pos += [(COMPARE_W / 2, -56.0), (-60.0, ERROR_Y - 10.0)]
    tick_labels += [f"{c.metric} per pair of the run ({'log' if log else 'linear'} y; x: the pair's index)", "error"]
    points, point_colors = [], []
    for side, v in ((na, a), (nb, b)):
        ok = np.isfinite(v)
        y = np.where(ok, to_y(np.where(ok, v, 1.0)), ERROR_Y)
        points += [(to_x(i), float(yy)) for i, yy in zip(index, y)]
        point_colors += [rgb(colors[side])] * len(v)
    rec.log(COMPARE_PAIRS,
            rr.LineStrips2D(strips + axes, colors=strip_colors + [AXIS_COLOR] * len(axes),
                            radii=strip_radii + [0.8] * len(axes)),
            rr.Points2D(points, colors=point_colors, radii=4.0),
            rr.AnyValues(pairs=names, index=index, a=a, b=b, only_a_fails=[float(n in only[na]) for n in names],
                         only_b_fails=[float(n in only[nb]) for n in names]), static=True)
    rec.log(f"{COMPARE_PAIRS}/ticks", rr.Points2D(tick_pos, radii=0.1, colors=[(255, 255, 255)], labels=tick_labels,
                                                    show_labels=True), static=True)
    legend = {na: colors[na], nb: colors[nb], f"only {na} fails (band)": _dim(colors[na]),
              f"only {nb} fails (band)": _dim(colors[nb])}
    log_legend(rec, legend, COMPARE_LEGEND, (0.0, COMPARE_H + 50.0))


def write_compare_recording(c, path: Path, indices: dict[str, int], markdown: str) -> Path:
    """compare.rrd (atomically): the plot of :func:`log_compare_plot` beside ``markdown`` (compare.md)."""
    import rerun as rr

    from fviz.record.writer import RecordingWriter

    na, nb = c.names
    title = f"{c.metric}: {na} vs {nb}, per pair (bands: only one fails)"
    with RecordingWriter(path, "fviz-compare", compare_blueprint(title)) as w:
        log_compare_plot(w.rec, c, indices)
        w.rec.log(COMPARE_TEXT, rr.TextDocument(markdown, media_type="text/markdown"), static=True)
    return Path(path)
