"""The recording's layout in one place: entity paths, colours and the stored blueprint.

Colours
    Every estimator has one fixed colour (:func:`estimator_colors`; the ground truth is white), used for all of it:
    epipolar lines, epipole, comparison bars, metric series, motion tracks and the probe's lines. Charts and plots
    have a dark background (``CHART_BACKGROUND``) so that white shows in any theme; their labels are white (Rerun
    draws them on grey boxes) beside the coloured bar. A point's residual (its distance to its epipolar line, px) is a
    separate, sequential and colour-blind-safe scale (viridis, 0 to ``RESIDUAL_MAX_PX``), given to keypoints through
    the class ids of the static annotation context, whose labels are the scale's legend.

Entity paths (``{v}`` is the view, ``a`` or ``b``; ``{e}`` an estimator name, ``gt`` for the ground truth):

    {v}/image                   EncodedImage (JPEG)
    est/{e}/matches             Points2D: both ends of every match, x_a in image a then x_b in image b (in the
                                root frame: b's shifted by ``offset_b``), coloured by e's residual (SED, px);
                                the class (hover) says the residual bin and whether e counts the match as an
                                inlier. One pair (inspect) stores only the ground truth's: an estimator's tab
                                shows its own classes there through a blueprint override (positions once)
    {v}/est/{e}/epilines        e's colour: LineStrips2D of the epipolar lines of sampled evaluation matches,
                                clipped to the image (in a from F^T x_b, in b from F x_a), and a cross at e's
                                epipole (name and position as hover text); outside the image or at infinity
                                the cross sits on the border and Arrows2D points towards the epipole
    {v}/epipoles                every F's epipole cross (and arrow) in its colour, for the overview
    reference                   (ground truth suspect) the reference F's epipolar lines of a few line matches in
                                both images (in the root frame: b's shifted by ``offset_b``), thick, in that F's
                                colour and labelled "REFERENCE"; drawn on the overview over the ground truth's
                                white lines of the same matches. Empty on a triage pair whose ground truth is fine
    gt/labelled                 (``--gt-matches``) the hand-labelled correspondences, both ends (root frame), large
                                points coloured by the ground truth's residual on them (the residual scale); those
                                at least RESIDUAL_MAX_PX off F_gt (fitted to them: a mislabel) ringed and labelled
                                with their residual. On the overview; the probe walks them
    compare                     (one pair) a bar chart drawn in 2D: per metric one bar per F in its colour
                                (LineStrips2D), labelled with the F's name and value (Points2D labels)
    pair/metrics                AnyValues: ``estimators`` (names) and one column per metric, in that order
                                (what ``fviz summary`` and the tests read)
    metrics/{metric}            Scalars (runs of many pairs): one named, coloured series per F on ``pair``
    metrics/{metric}/log10      Scalars: the log10 an error metric's plot draws (LOG_METRICS, log_values)
    motion/{track}              Scalars (eval.rrd: they follow consecutive pairs, not triage's ranks): per F the
                                image-a epipole (``epipole_x``,
                                ``epipole_y`` px; NaN when at infinity, its direction in ``epipole_dir_deg``),
                                ``rotation_deg`` (angle of R) and the translation direction ``t_x``, ``t_y``,
                                ``t_z`` (unit, the ground truth's sign)
    {v}/probe, probe/text       the ``probe`` timeline (inspect): step k rings the k-th point the probe walks
                                (probe.probe_points: most telling first, near-duplicates skipped) in both
                                images (yellow, PROBE_MARK_PX on screen and PROBE_RING_PX in the image), joins the
                                two rings, and draws its epipolar line under every F in the F's colour; the text
                                lists the residuals
    probe/zoom/{v}              Transform3D on ``probe``: the probed end in image v (root frame), the origin of
                                that zoomed view (PROBE_ZOOM_PX around it)
    errors/{e}                  TextLog: why an estimator failed on this pair
    pair/fundamental            AnyValues: ``estimators`` (names, ``gt`` first when known; failed ones left out),
                                ``F`` (their F's, 9 values each, row-major), ``size_a``, ``size_b`` (w, h):
                                what a click needs (:mod:`fviz.interactive`)
    {v}/click, {v}/click/label  a click (:mod:`fviz.interactive`, logged live by the notebook viewer and
                                ``fviz open --web``, never stored by fviz): in the clicked image a yellow ring,
                                in the other the point's epipolar line under every F in its colour and the
                                match partner's ring; the label lists the match's residual (SED) under each F
    click/text                  TextDocument (Markdown): the click, its match and the residuals
    summary                     TextDocument (Markdown): pair, compact metrics table, F matrices below
    pair/info                   TextDocument: the pair's name (what ``fviz summary`` lists)
    pair/verdict                TextDocument (Markdown): the pair's verdict in one line (:func:`fviz.verdicts.pair_verdict`:
                                matcher, estimator, ground truth suspect, no evaluation matches, ...) with the number
                                behind it, shown above the tabs of every pair view (triage: its banner's first line)

Training (``fviz train``'s train.rrd, :func:`fviz.log_training_step`; ``{k}`` names a watched validation pair):

    train/{curve}, val/{metric} Scalars on ``step`` (``fviz train``): loss, learning rate, gradient norm, validation
    watch/{k}/{v}/image         EncodedImage (JPEG), static: the pair as the network sees it (b below or beside a)
    watch/{k}/{v}/gt            LineStrips2D, static: the ground truth's epipolar lines of the pair's fixed
                                correspondences (white) and a cross at its epipole
    watch/{k}/{v}/net           LineStrips2D on ``step``: the network's lines of the same correspondences (in
                                its colour, ``watch_colors``) and its epipole's cross (arrow when outside)
    watch/{k}/{v}/baseline      the same for a baseline F given (``fviz train``: the training targets' mean F), cyan
    watch/{k}/points            Points2D on ``step``: both ends of the correspondences (b's shifted by
                                ``offset_b``), coloured by the network's residual (SED, px; the residual scale)
    watch/{k}/sed_px[/baseline] Scalars on ``step``: the network's (the baseline's) median SED on them (px)
    watch/{k}/fundamental       AnyValues on ``step``, as ``pair/fundamental``: ``gt``, ``network``, the baseline's
                                name; what a click needs. A click's marks: ``watch/{k}/{v}/click`` (:mod:`fviz.interactive`)

Image b is drawn below image a or right of it, ``b`` translated by :func:`fviz.record.placement.offset_b`, so one 2D
view shows both and a match is one segment; marks that keep their size on screen are scaled by
:func:`fviz.record.placement.screen_unit` (:mod:`fviz.record.placement`). A run's plots' titles, log10 values and y
ranges: :mod:`fviz.record.plots`.

Timelines: every pair sits at one index of ``pair`` (``inspect`` writes 0, ``eval`` one per pair; ``triage`` adds
``rank``; ``fviz.log_result`` the index given, :mod:`fviz.record.stream_pairs`); ``inspect`` logs the pair at
``probe`` = 0 too, so each probe step shows over the pair (a stream of many pairs opens on ``pair``).

The stored blueprint (:func:`blueprint`) opens on an **overview** tab (both images stacked with the ground truth's
residuals and lines, every F's epipole, the comparison chart and the summary), then **one tab per estimator** named
after it (image a above image b with only that estimator's keypoints, lines and epipole, and the ground truth's lines
in white), then **probe** (inspect); runs of many pairs add **metrics** (errors on log10 axes; over ``pair``, or as
points over triage's ``rank``) and, over ``pair``, **motion**, and open on them when the recording holds no images.
Above the tabs of a recording with images: the pair's verdict, one line (triage: its banner, the verdict first).
``fviz open FILE --tab NAME`` rebuilds this blueprint from the file (:func:`fviz.record.rebuild.recording_blueprint`)
with another tab active.

Past the house's 500 lines (tests/test_architecture.py, OVERSIZED): the entity paths with their documentation, the
colours and both recordings' blueprints stay in this one place; the maths is in placement, charts and plots.
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from fviz.record.charts import compare_bounds, curves_bounds
from fviz.record.placement import images_extent, view_extent
from fviz.record.plots import LOG_METRICS, off_scale_note, plot_title

TIMELINE = "pair"
TRAIN_TIMELINE = "step"  # train.rrd and log_training_step: the optimizer step
RANK_TIMELINE = "rank"  # triage.rrd: the worst pair first
PROBE_TIMELINE = "probe"
VIEWS = ("a", "b")
GT = "gt"

# ---------------------------------------------------------------------------------------------- colours

GT_COLOR = (255, 255, 255)
# Rerun writes a label in its entity's colour on a translucent box over the photos: black reads there. Text below
# the images (the estimator's numbers, the residual scale's ends) sits on Rerun's label box over the view's
# background: dark grey (28) in the dark theme (fviz's page, the native viewer), light (239) in the light one (Rerun's
# web viewer in a light browser). Mid grey reads on both (contrast ~3.9:1 each; black was 1.2:1 on the dark box).
LABEL_ON_PHOTO = (0, 0, 0)
LABEL_OFF_PHOTO = (120, 120, 120)
PROBE_COLOR = (255, 220, 0)  # the probe's rings and join (no keypoints in that tab: no clash with the residual scale)
# Fixed colours of the estimators fviz knows; chosen far (> 80 in RGB) from each other, from grey (the
# photos), from white (the ground truth) and from the viridis residual scale, so none is mistaken for another.
PALETTE = (
    (255, 150, 0),    # orange
    (0, 220, 255),    # cyan
    (230, 50, 230),   # magenta
    (255, 40, 60),    # red
    (170, 120, 255),  # violet
    (40, 90, 255),    # blue
    (255, 160, 140),  # salmon
    (170, 110, 50),   # brown
)
KNOWN_COLORS = {"magsac": 0, "ransac": 1, "8point": 2, "deep": 3, "lmeds": 4, "7point": 5, "ahead": 6, "oracle-mean": 7}
CHART_BACKGROUND = (32, 32, 36)  # charts and plots: dark, so that the ground truth's white shows in any theme
# No ground truth: the comparison chart's NSGD between every two estimators, one cell each (green: they agree)
AGREE_COLOR, DIFFER_COLOR, SAME_COLOR = (40, 170, 80), (190, 60, 50), (70, 70, 76)


def estimator_colors(names: Iterable[str]) -> dict[str, tuple[int, int, int]]:
    """name -> (r, g, b). Known estimators and ``gt`` always get their own colour; other names (user
    functions, ``deep:PATH`` models) the palette's free colours in the order given, then evenly spaced hues."""
    names = list(dict.fromkeys(names))
    out = {n: (GT_COLOR if n == GT else PALETTE[KNOWN_COLORS[n]]) for n in names if n == GT or n in KNOWN_COLORS}
    taken = set(out.values())
    free = [c for c in PALETTE if c not in taken]
    others = [n for n in names if n not in out]
    for i, n in enumerate(others):
        out[n] = free[i] if i < len(free) else _hue(i - len(free), len(others) - len(free))
    return {n: out[n] for n in names}


def _hue(i: int, n: int) -> tuple[int, int, int]:
    import colorsys

    r, g, b = colorsys.hsv_to_rgb((0.08 + i / max(n, 1)) % 1.0, 0.75, 1.0)
    return int(255 * r), int(255 * g), int(255 * b)


# Residual scale of the keypoints: class c holds residuals in [c, c + 1) * RESIDUAL_BIN_PX; the last one
# everything from RESIDUAL_MAX_PX up (and NaN).
RESIDUAL_BIN_PX = 0.25
RESIDUAL_MAX_PX = 3.0
RESIDUAL_CLASSES = int(RESIDUAL_MAX_PX / RESIDUAL_BIN_PX) + 1


def residual_classes(residual_px: np.ndarray, inlier: np.ndarray | None = None) -> np.ndarray:
    """Residual (px) -> class id of its bin (0 .. RESIDUAL_CLASSES - 1, NaN -> the last); outliers of the
    estimator (``inlier`` False) get the same bin + RESIDUAL_CLASSES (same colour, their own label).
    (N,), (N,) -> (N,) uint16."""
    r = np.nan_to_num(np.asarray(residual_px, float), nan=np.inf)
    cls = np.minimum(r / RESIDUAL_BIN_PX, RESIDUAL_CLASSES - 1).astype(np.uint16)
    return cls if inlier is None else cls + RESIDUAL_CLASSES * (~np.asarray(inlier, bool)).astype(np.uint16)


def class_color(cls: int | np.ndarray) -> np.ndarray:
    """Viridis from class 0 (dark blue-violet: on the line) to the last class (yellow: far off it).  -> (..., 3) uint8."""
    import cv2

    t = np.asarray(cls, float) / (RESIDUAL_CLASSES - 1)
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_VIRIDIS)[:, 0, ::-1]
    # start a fifth into the map: its darkest purple vanishes on dark photos
    return lut[np.round(50 + t * 205).astype(int)]


def annotation_context():
    """The residual legend: one class per bin, coloured and labelled."""
    import rerun as rr

    infos = []
    for outlier in (False, True):
        for c in range(RESIDUAL_CLASSES):
            lo = c * RESIDUAL_BIN_PX
            label = f">= {lo:g} px" if c == RESIDUAL_CLASSES - 1 else f"{lo:g}-{lo + RESIDUAL_BIN_PX:g} px"
            label = f"residual {label}, {'outlier' if outlier else 'inlier'}"
            infos.append(rr.AnnotationInfo(id=c + outlier * RESIDUAL_CLASSES, label=label,
                                           color=tuple(int(v) for v in class_color(c))))
    return rr.AnnotationContext(infos)


# ---------------------------------------------------------------------------------------------- entity paths

SUMMARY = "summary"
PAIR_INFO = "pair/info"
VERDICT = "pair/verdict"
PAIR_METRICS = "pair/metrics"
COMPARE = "compare"
PROBE_TEXT = "probe/text"
TRIAGE_TAGS = "triage/tags"  # triage.rrd: the rank's tags, above the tabs
END = "fviz/end"  # static, the last message of a recording written without Rerun's footer (see record.writer)

# Metric series of a run (``metrics/{key}``), one per F (their titles: fviz.record.plots). f_dist is left out: it
# misranks (docs/metrics.md).
SERIES_METRICS = ("sed_median", "rot_err_deg", "trans_err_deg", "nsgd", "epipole_err_deg", "inlier_ratio")
MOTION_TRACKS = (
    ("epipole_x", "epipole x in image a (px)"),
    ("epipole_y", "epipole y in image a (px)"),
    ("epipole_dir_deg", "epipole direction when at infinity (deg)"),
    ("rotation_deg", "rotation angle (deg)"),
    ("t_x", "translation direction x"),
    ("t_y", "translation direction y"),
    ("t_z", "translation direction z"),
)


def image(view: str) -> str:
    return f"{view}/image"


def est(view: str, name: str, what: str) -> str:
    """what: epilines."""
    return f"{view}/est/{name}/{what}"


def matches(name: str) -> str:
    """Both ends of the matches, coloured by ``name``'s residual (see the module docstring)."""
    return f"est/{name}/matches"


def matches_owner(path: str) -> str | None:
    """The estimator of a :func:`matches` path, None for any other path."""
    inner = path.removeprefix("est/").removesuffix("/matches")
    return inner if path == matches(inner) and inner else None


def metric(key: str) -> str:
    """A metric's values over the pairs (what readers read)."""
    return f"metrics/{key}"


def metric_plot(key: str) -> str:
    """What a metric's plot draws: ``metrics/{key}/log10`` (log10 of the values, :func:`fviz.record.plots.log_values`) for an
    error (LOG_METRICS), else the values."""
    return f"{metric(key)}/log10" if key in LOG_METRICS else metric(key)


def motion(track: str) -> str:
    return f"motion/{track}"


LEGEND = "legend"  # runs: one coloured bar and name per series (the plots' own legends would cover their data)
RUN_SUMMARY = "run/summary"  # runs: the run's standard figures (static)
CURVES = "curves"  # runs (eval): the cumulative error curves, one 2D chart


REFERENCE = "reference"  # the F to trust when the ground truth is suspect: its lines on the overview
REFERENCE_LINES = 10  # of the ground truth's line matches (the first ones): the reference's lines beside them
REFERENCE_RADIUS = 1.5  # thicker than every other line (0.9), so that it reads as the one to trust


LABELLED = "gt/labelled"  # --gt-matches: the hand-labelled correspondences (see the module docstring)
LABELLED_RADIUS_PX = 4.0  # screen px: larger than a keypoint, so that they stand out among them
PAIR_FS, CLICK_TEXT = "pair/fundamental", "click/text"
EXCLUDED = "edit/excluded"  # the matches a user excluded (fviz.editing): grey dots over both images, root frame


def click(view: str) -> str:
    return f"{view}/click"


def click_label(view: str) -> str:
    return f"{view}/click/label"


def click_halo(view: str) -> str:
    return f"{view}/click/halo"


def probe(view: str) -> str:
    return f"{view}/probe"


PROBE_RING_PX = 3.0  # image px: a line outside this ring misses the match by more than 3 px (seen in the zoom)
PROBE_MARK_PX = 12.0  # screen px: the ring that shows where the match is on the whole images
PROBE_ZOOM_PX = 24.0  # image px each side of the match in the zoomed views


def probe_zoom(view: str) -> str:
    """A frame at the probed point of image ``view`` (a Transform3D on ``probe``): the zoomed view's origin."""
    return f"probe/zoom/{view}"


def epipoles(view: str) -> str:
    return f"{view}/epipoles"


def error(name: str) -> str:
    return f"errors/{name}"


# ---------------------------------------------------------------------------------------------- blueprint
# Every view, container and override costs 1.5-5 KB of the file (a chunk with its own schema each, whatever
# it holds): the layout keeps to the views a reader needs, one 2D view per tab for both images.


def _images_view(sizes: tuple[tuple[int, int], tuple[int, int]], name: str, contents: list[str], overrides=None):
    """Image a above image b in one 2D view, with ``contents`` (entity path queries) over them."""
    import rerun.blueprint as rrb

    w, bottom, m = view_extent(sizes)
    clicks = [f"+ {click(v)}/**" for v in VIEWS] + [f"+ {EXCLUDED}"]  # drawn live (fviz.interactive, fviz.editing)
    return rrb.Spatial2DView(origin="/", contents=[f"+ {image('a')}", f"+ {image('b')}", *contents, *clicks], name=name,
                             visual_bounds=rrb.VisualBounds2D(x_range=[-0.5 - m, w - 0.5 + m],
                                                              y_range=[-0.5 - m, bottom - 0.5]),
                             overrides=overrides)


def overview_tab(names: Sequence[str], sizes, single_pair: bool, gt: bool = True, notice: str = ""):
    """Both images with the ground truth's residuals and lines (without ground truth: the last estimator's)
    and every F's epipole; beside them the comparison (bars, one pair) and the summary.  ``notice`` opens the
    title (e.g. that the ground truth is suspect)."""
    import rerun.blueprint as rrb

    ref = GT if gt or not names else names[-1]  # without ground truth: the last estimator's (default: magsac)
    contents = ([f"+ {matches(ref)}"] + [f"+ {v}/est/{ref}/**" for v in VIEWS] + [f"+ {epipoles(v)}" for v in VIEWS]
                + [f"+ {REFERENCE}", f"+ {LABELLED}"])
    title = ("ground truth: residuals (keypoints) and lines (white)" if ref == GT
             else f"no ground truth: {ref}'s residuals (keypoints) and lines")
    images = _images_view(sizes, f"{notice}{title}; every F's epipole", contents)
    x_range, y_range = compare_bounds(len(names) + gt, gt)
    chart = rrb.VisualBounds2D(x_range=x_range, y_range=y_range)
    side = [rrb.Spatial2DView(origin=COMPARE, name="comparison (one bar per F, in its colour)", visual_bounds=chart,
                              background=CHART_BACKGROUND)] if single_pair else []
    side.append(rrb.TextDocumentView(origin=SUMMARY, name="summary"))
    return rrb.Horizontal(images, rrb.Vertical(*side, row_shares=[3, 2][: len(side)]), column_shares=[5, 2], name="overview")


def estimator_tab(name: str, sizes, classes: np.ndarray | None = None):
    """Both images with only this estimator: its keypoints (residual colours), its lines and epipole (its
    colour) and the ground truth's lines and epipole (white).

    ``classes`` (one pair): the estimator's classes of ``matches`` (2N), shown on the ground truth's matches
    (the same points) by a blueprint override, so that the positions are stored once."""
    import rerun as rr

    lines = [f"+ {est(v, name, 'epilines')}" for v in VIEWS] + [f"+ {est(v, GT, 'epilines')}" for v in VIEWS]
    if classes is None:
        return _images_view(sizes, name, [f"+ {matches(name)}"] + lines)
    override = rr.Points2D.from_fields(class_ids=np.asarray(classes, np.uint16))
    return _images_view(sizes, name, [f"+ {matches(GT)}"] + lines, overrides={matches(GT): override})


def probe_tab(sizes):
    """Both images with the probed match; beside them each end zoomed (a view whose origin follows the match,
    showing the same images and lines PROBE_ZOOM_PX around it) and the residuals."""
    import rerun.blueprint as rrb

    contents = [f"+ {probe(v)}" for v in VIEWS]
    images = _images_view(sizes, "probe: the match (ring, joined) and its epipolar line under every F", contents)
    zoom = rrb.VisualBounds2D(x_range=[-PROBE_ZOOM_PX, PROBE_ZOOM_PX], y_range=[-PROBE_ZOOM_PX, PROBE_ZOOM_PX])
    zooms = [rrb.Spatial2DView(origin=probe_zoom(v), name=f"zoom {v}",
                               contents=[f"+ {image(u)}" for u in VIEWS] + contents, visual_bounds=zoom) for v in VIEWS]
    side = rrb.Vertical(rrb.Horizontal(*zooms), rrb.TextDocumentView(origin=PROBE_TEXT, name="probe: this match"),
                        row_shares=[2, 3])
    return rrb.Horizontal(images, side, column_shares=[3, 1], name="probe")


def legend_view(origin: str, n: int, name: str, pitch: float = 24.0):
    """A 2D view framing the legend rows :func:`fviz.record.run_plots.log_legend` draws (``n`` of them)."""
    import rerun.blueprint as rrb

    return rrb.Spatial2DView(origin=origin, name=name, background=CHART_BACKGROUND,
                             visual_bounds=rrb.VisualBounds2D(x_range=[-20.0, 260.0], y_range=[-pitch, n * pitch]))


def _series_grid(entity_of, tracks: Sequence[tuple[str, str]], name: str, ranges: dict | None, n_series: int):
    """One plot per track, its y range from ``ranges`` ({path: series_range or None}; a track with no finite
    value is left out), the plots' legends hidden (they covered the data) and one legend view instead. A series
    cut off a plot (drawn as points there, see :func:`fviz.record.run_plots.series_styles`) has its 5-95 % band in
    the plot's title."""
    import rerun.blueprint as rrb
    from rerun.blueprint.archetypes import PlotBackground, PlotLegend

    dark = PlotBackground(color=CHART_BACKGROUND, show_grid=True)  # the ground truth's white series shows
    views, any_cut = [], False
    for k, title in tracks:
        path = entity_of(k)
        if ranges is not None and ranges.get(path) is None:
            continue  # nothing to plot (an epipole never at infinity)
        axis, note = None, ""
        if ranges is not None:
            lo, hi, cut = ranges[path]
            axis = rrb.ScalarAxis(range=(lo, hi), zoom_lock=False)
            note = off_scale_note(cut)
            any_cut |= bool(cut)
        views.append(rrb.TimeSeriesView(origin=path, name=title + note, background=dark, axis_y=axis,
                                        plot_legend=PlotLegend(visible=False)))
    views.append(legend_view(LEGEND, n_series, "legend" + (" (scroll a plot to zoom out: off-scale series)" if any_cut else "")))
    return rrb.Grid(*views, name=name)


def curves_tab(n_series: int):
    """The cumulative error curves (runs of eval): one 2D chart, drawn by :func:`fviz.record.run_plots.log_curves`,
    its legend below."""
    import rerun.blueprint as rrb

    x_range, y_range = curves_bounds(n_series)
    bounds = rrb.VisualBounds2D(x_range=x_range, y_range=y_range)
    return rrb.Spatial2DView(origin=CURVES, name="curves", background=CHART_BACKGROUND, visual_bounds=bounds)


VERDICT_SHARE = 13  # the tabs' height below the verdict's (1)


def blueprint(names: Sequence[str], sizes: Sequence | None, single_pair: bool, head: bool = False,
              active: str | None = None, classes: dict[str, np.ndarray] | None = None, ranges: dict | None = None,
              curves: bool = False, run_summary: bool = False, notice: str = "", verdict: bool = False, timeline: str | None = None):
    """The stored layout. ``names``: the F's (``gt`` among them or not); ``sizes``: (w, h) of image a and b,
    None when the recording holds no images (eval without --full); ``single_pair``: inspect (comparison
    bars and the probe) rather than a run (metric series and motion tracks over the pair timeline);
    ``head``: triage's banner and tags above the tabs (and the time panel on ``rank``); ``active``: the tab it
    opens on (default the first); ``classes``: (one pair) each estimator's keypoint classes, see
    :func:`estimator_tab`; runs: ``ranges`` the plots' y ranges ({path: :func:`fviz.record.plots.series_range`}), ``curves`` a
    tab of cumulative error curves, ``run_summary`` a summary tab with the run's figures; ``notice``: a
    warning put in the overview's title (a suspect ground truth); ``verdict``: the pair's verdict (``VERDICT``) above
    the tabs (with ``head`` the banner opens with it instead); ``timeline``: the time panel's (default: ``probe`` for one
    pair, ``rank`` with ``head``, else ``pair``). ``sizes`` may list many pairs' (:func:`fviz.record.placement.view_extent`)."""
    import rerun.blueprint as rrb

    ests = [n for n in names if n != GT]
    classes = classes or {}
    tabs = []
    if sizes is not None:
        tabs.append(overview_tab(ests, sizes, single_pair, gt=GT in names, notice=notice))
        tabs += [estimator_tab(n, sizes, classes.get(n)) for n in ests]
        if single_pair:
            tabs.append(probe_tab(sizes))
    if not single_pair:
        tabs.append(_series_grid(metric_plot, [(k, plot_title(k)) for k in SERIES_METRICS], "metrics", ranges, len(names)))
        if not head:  # the tracks follow consecutive pairs: not over triage's ranks
            tabs.append(_series_grid(motion, MOTION_TRACKS, "motion", ranges, len(names)))
        if curves:
            tabs.append(curves_tab(len(ests)))
        if run_summary:
            tabs.append(rrb.TextDocumentView(origin=RUN_SUMMARY, name="summary"))
    titles = [str(t.name) for t in tabs]
    if active is not None and active not in titles:
        raise ValueError(f"no tab {active!r} (tabs: {', '.join(titles)})")
    root = rrb.Tabs(*tabs, active_tab=titles.index(active) if active else 0)
    if head:
        root = rrb.Vertical(rrb.TextDocumentView(origin=TRIAGE_TAGS, name="triage"), root, row_shares=[1, 7])
    elif verdict:  # a title bar and two lines of text (a long verdict wraps in a narrow window)
        root = rrb.Vertical(rrb.TextDocumentView(origin=VERDICT, name="verdict"), root, row_shares=[1, VERDICT_SHARE])
    # paused, so that the viewer opens on the probe's first step (the worst match) and play walks from there
    timeline = timeline or (PROBE_TIMELINE if single_pair else RANK_TIMELINE if head else TIMELINE)
    time_panel = rrb.TimePanel(state="collapsed", timeline=timeline,
                               play_state="paused", fps=2.0)
    return rrb.Blueprint(root, time_panel, collapse_panels=True)


# ---------------------------------------------------------------------------------------------- training

WATCH = "watch"  # the watched validation pairs of a training run (see the module docstring)
NET, BASELINE, NETWORK = "net", "baseline", "network"  # entities of the network's and a baseline's F; the network's name


def watch(name: str, what: str = "") -> str:
    """``watch/{name}`` or ``watch/{name}/{what}`` (what: ``a/image``, ``b/net``, ``points``, ``sed_px``, ...)."""
    return f"{WATCH}/{name}" + (f"/{what}" if what else "")


def watch_colors() -> dict[str, tuple[int, int, int]]:
    """The network's colour (the palette's first: orange), the baseline's (its second: cyan) and the ground truth's."""
    return {NET: PALETTE[0], BASELINE: PALETTE[1], GT: GT_COLOR}


# train.rrd's curves tab: (plot title, its series); each series' name and colour in TRAIN_SERIES.
TRAIN_PLOTS = (
    ("loss: training batches vs held-out validation pairs", ("train/loss", "val/loss")),
    ("validation median SED (px): network vs the constants (training pairs' mean F, straight ahead)",
     ("val/sed_px", "val/mean_f_sed_px", "val/ahead_sed_px")),
    ("validation |x_b^T F x_a| (unit F): mean, mean square", ("val/epi_abs", "val/epi_sqr")),
    ("validation F distance", ("val/f_dist",)),
    ("learning rate", ("train/lr",)),
    ("gradient norm", ("train/grad_norm",)),
)
TRAIN_SERIES = {
    "train/loss": ("training loss", PALETTE[0]), "val/loss": ("validation loss", PALETTE[1]),
    "val/sed_px": ("network", PALETTE[1]), "val/mean_f_sed_px": ("mean F of the training pairs", GT_COLOR),
    "val/ahead_sed_px": ("straight ahead", PALETTE[3]), "val/constant_sed_px": ("constant F", GT_COLOR),
    "val/epi_abs": ("mean", PALETTE[1]), "val/epi_sqr": ("mean square", PALETTE[2]),
    "val/f_dist": ("F distance", PALETTE[1]), "train/lr": ("learning rate", PALETTE[0]),
    "train/grad_norm": ("gradient norm", PALETTE[0]),
}

# each validation's line: the network beside both constants ("the model is no better than the constant: ..."),
# a TextLog on ``step`` (fviz.train.validation.versus_constants), shown under the curves
TRAIN_VERDICT = "val/verdict"


def training_style(key: str) -> dict:
    """SeriesLines fields (name, colour) of a train.rrd curve; a curve fviz does not know keeps its key."""
    name, color = TRAIN_SERIES.get(key, (key.rpartition("/")[2], PALETTE[4]))
    return {"names": [name], "colors": [color]}


def training_blueprint(names: Sequence[str], sizes: Sequence[tuple[tuple[int, int], tuple[int, int]]], curves: bool = False,
                       baseline: str | None = None):
    """train.rrd's layout: one tab per watched pair (image a above b, the network's lines and epipole beside the
    ground truth's and those of the ``baseline`` named, keypoints by residual; the SEDs over ``step`` below), and with
    ``curves`` a tab of the training and validation curves (TRAIN_PLOTS: the two losses in one plot, the validation SED
    beside the two constants', legends on) above each validation's verdict against the constants (TRAIN_VERDICT). The
    time panel opens on ``step``: scrubbing it shows the lines converge."""
    import rerun.blueprint as rrb
    from rerun.blueprint.archetypes import PlotBackground

    dark = PlotBackground(color=CHART_BACKGROUND, show_grid=True)
    tabs = []
    for name, pair_sizes in zip(names, sizes):
        w, h = images_extent(*pair_sizes)
        vs = f"{NETWORK} (orange) vs {baseline + ' (cyan) vs ' if baseline else ''}ground truth (white)"
        images = rrb.Spatial2DView(origin=watch(name), name=f"{name}: {vs}",
                                   visual_bounds=rrb.VisualBounds2D(x_range=[-0.5, w - 0.5], y_range=[-0.5, h - 0.5]))
        plot = rrb.TimeSeriesView(origin=watch(name, "sed_px"), name=f"{name}: median SED (px)", background=dark)
        tabs.append(rrb.Vertical(images, plot, row_shares=[3, 1], name=f"pair {name}"))
    if curves:
        grid = rrb.Grid(*(rrb.TimeSeriesView(origin="/", contents=[f"+ {k}" for k in keys], name=title, background=dark)
                          for title, keys in TRAIN_PLOTS))
        verdicts = rrb.TextLogView(origin=TRAIN_VERDICT, name="validation vs the constants")
        tabs.append(rrb.Vertical(grid, verdicts, row_shares=[5, 1], name="curves"))
    root = rrb.Tabs(*tabs) if tabs else rrb.Tabs(rrb.TextDocumentView(origin="/", name="empty"))
    time_panel = rrb.TimePanel(state="expanded", timeline=TRAIN_TIMELINE, play_state="paused", fps=4.0)
    return rrb.Blueprint(root, time_panel, collapse_panels=False)
