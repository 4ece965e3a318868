"""compare.rrd: what ``fviz compare`` found, pair by pair, on one screen. Per pair of the run (x: its index) each
side's value of the metric in its colour (log y for errors, linear for ratios), the metric's fail threshold as a
line, a band behind every pair where only one side fails (in that side's colour, dimmed: a stretch of consecutive
pairs shows as one wide band), no value (an error) as a mark above the axes; beside it compare.md. Drawn in 2D
(Rerun's plots have no log axis) with the layout's entity paths (:mod:`fviz.record.layout`).

fviz's page draws a pair whose point is clicked (:class:`fviz.api.runpairs.ComparedPairs`): the recording names the
runs compared (``COMPARE_SOURCE``), :func:`read_chart` reads the points back and :meth:`Chart.pair_at` maps a
selection on the chart to its pair; :func:`compare_blueprint` with ``sizes`` adds the pair's images below the chart."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fviz.record import layout as L

ERROR_Y = -16.0  # where a pair without a value is marked, above the axes
AXIS_COLOR = (200, 200, 200)
# compare.rrd (``fviz compare``): the metric of both sides per pair of the run, drawn in 2D (y down), and compare.md
COMPARE_PAIRS = "compare/pairs"
COMPARE_POINTS = "compare/pairs/points"  # side a's value of pair k at instance k, side b's at N + k (hover: the pair)
COMPARE_SOURCE = "compare/source"  # static AnyValues: the runs compared (relative to the recording's folder), etc.
COMPARE_LEGEND = "compare/legend"
COMPARE_TEXT = "compare/text"
COMPARE_W, COMPARE_H = 1000.0, 360.0  # the plot's axes, in 2D units
REACH = 12.0  # a click this close to a pair's point (2D units: ~screen px at the chart's framing) picks that pair


def compare_title(metric: str, na: str, nb: str) -> str:
    """The chart's view name (what a selection on it reports as ``view_name``)."""
    return f"{metric}: {na} vs {nb}, per pair (bands: only one fails)"


def compare_blueprint(title: str, sizes=None, names=()):
    """compare.rrd's layout: the per-pair plot (its legend below it) beside compare.md; with ``sizes`` (a pair's
    images, or many pairs', as :func:`fviz.record.layout.overview_tab` takes them) a run's pair below (the F's
    ``names``: its images, matches, lines, summary) and the time panel on ``pair`` (where each pair drawn sits)."""
    import rerun.blueprint as rrb

    bounds = rrb.VisualBounds2D(x_range=[-90.0, COMPARE_W + 40.0], y_range=[-70.0, COMPARE_H + 150.0])
    plot = rrb.Spatial2DView(origin="compare", contents=[f"+ {COMPARE_PAIRS}/**", f"+ {COMPARE_LEGEND}"], name=title,
                             background=L.CHART_BACKGROUND, visual_bounds=bounds)
    text = rrb.TextDocumentView(origin=COMPARE_TEXT, name="compare.md")
    root = rrb.Horizontal(plot, text, column_shares=[5, 2])
    if sizes is None:
        return rrb.Blueprint(root, rrb.TimePanel(state="hidden"), collapse_panels=True)
    pair = L.overview_tab([n for n in names if n != L.GT], sizes, single_pair=False, gt=L.GT in names)
    return rrb.Blueprint(rrb.Vertical(root, pair, row_shares=[2, 3]),
                         rrb.TimePanel(state="collapsed", timeline=L.TIMELINE, play_state="paused"), collapse_panels=True)


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
            rr.AnyValues(pairs=names, index=index, a=a, b=b, only_a_fails=[float(n in only[na]) for n in names],
                         only_b_fails=[float(n in only[nb]) for n in names]), static=True)
    hover = [f"{n} (#{i:g}): {side} {v:.4g}" if math.isfinite(v) else f"{n} (#{i:g}): {side} error"
             for side, vals in ((na, a), (nb, b)) for n, i, v in zip(names, index, vals)]  # the pair, clickable
    rec.log(COMPARE_POINTS, rr.Points2D(points, colors=point_colors, radii=4.0, labels=hover, show_labels=False),
            static=True)
    rec.log(f"{COMPARE_PAIRS}/ticks", rr.Points2D(tick_pos, radii=0.1, colors=[(255, 255, 255)], labels=tick_labels,
                                                    show_labels=True), static=True)
    legend = {na: colors[na], nb: colors[nb], f"only {na} fails (band)": _dim(colors[na]),
              f"only {nb} fails (band)": _dim(colors[nb])}
    log_legend(rec, legend, COMPARE_LEGEND, (0.0, COMPARE_H + 50.0))


def write_compare_recording(c, path: Path, indices: dict[str, int], markdown: str) -> Path:
    """compare.rrd (atomically): the plot of :func:`log_compare_plot` beside ``markdown`` (compare.md)."""
    import rerun as rr

    from fviz.record.writer import RecordingWriter

    with RecordingWriter(path, "fviz-compare", compare_blueprint(compare_title(c.metric, *c.names))) as w:
        log_compare_plot(w.rec, c, indices)
        w.rec.log(COMPARE_TEXT, rr.TextDocument(markdown, media_type="text/markdown"), static=True)
        log_compare_source(w.rec, c, Path(path).parent)
    return Path(path)


def _relative(run, folder: Path) -> str:
    """``run``'s folder as seen from ``folder`` (both moved together, still found), absolute where none is."""
    try:
        return os.path.relpath(Path(run).absolute(), Path(folder).absolute())
    except ValueError:  # another drive
        return str(Path(run).absolute())


def log_compare_source(rec, c, folder: Path) -> None:
    """``COMPARE_SOURCE``: what the chart compares (``runs``: both sides' run folders relative to ``folder``, the
    recording's; ``estimators``, ``metric``): where fviz's page reads a clicked pair from."""
    import rerun as rr

    rec.log(COMPARE_SOURCE, rr.AnyValues(runs=[_relative(c.a.run, folder), _relative(c.b.run, folder)],
                                         estimators=list(c.names), metric=[c.metric]), static=True)


@dataclass
class Chart:
    """A compare.rrd's chart read back: the pairs (``names``, N; ``index`` (N,) their place in run a), the points
    (``points`` (2N, 2): side a's, then side b's), the runs compared (``runs``: two folders, the same one for two
    estimators of one run), the view's ``title``."""

    names: list[str]
    index: list[int]
    points: "np.ndarray"
    runs: tuple[Path, Path]
    title: str

    def pair_at(self, entity_path: str | None, instance_id: int | None = None, position=None,
                view_name: str | None = None) -> int | None:
        """A selection -> the pair clicked (its place in ``names``), None off the chart or away from every pair.
        On the chart (its view, or one of its entities): the point nearest ``position`` (the chart's frame) within
        REACH, else the pair whose column (x) the position falls in, within the axes; without a position, the
        instance of a point (Rerun reports the entity hovered a frame earlier: the position is trusted first)."""
        path = (entity_path or "").strip("/")
        on_chart = view_name == self.title or path == "compare" or path.startswith("compare/")
        if not on_chart or not self.names:
            return None
        n = len(self.names)
        if position is not None and len(position) >= 2 and None not in tuple(position)[:2]:
            p = np.asarray(tuple(position)[:2], float)
            d = np.linalg.norm(self.points - p, axis=1)
            if d.min() <= REACH:
                return int(np.argmin(d)) % n
            x = self.points[:n, 0]
            inside = x.min() - REACH <= p[0] <= x.max() + REACH and ERROR_Y - REACH <= p[1] <= COMPARE_H
            return int(np.argmin(np.abs(x - p[0]))) if inside else None
        if path == COMPARE_POINTS and instance_id is not None and 0 <= instance_id < 2 * n:
            return instance_id % n
        return None


def read_chart(path: str | Path) -> Chart | None:
    """The chart of the compare.rrd at ``path`` (:class:`Chart`), None for any other recording (or a compare.rrd
    written before its runs were recorded in it)."""
    from fviz.record.reader import column, entity_paths

    path = Path(path)
    if COMPARE_SOURCE not in entity_paths(path):
        return None
    runs = column(path, COMPARE_SOURCE, "runs")[0]
    estimators = column(path, COMPARE_SOURCE, "estimators")[0]
    metric = column(path, COMPARE_SOURCE, "metric")[0][0]
    points = np.asarray(column(path, COMPARE_POINTS, "Points2D:positions")[0], float).reshape(-1, 2)
    return Chart(list(column(path, COMPARE_PAIRS, "pairs")[0]), [int(i) for i in column(path, COMPARE_PAIRS, "index")[0]],
                 points, tuple(Path(os.path.normpath(path.parent / r)) for r in runs), compare_title(metric, *estimators))
