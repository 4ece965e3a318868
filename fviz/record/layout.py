"""The recording's layout in one place: entity paths, colours and the stored blueprint.

Entity paths (``{v}`` is the view, ``a`` or ``b``; ``{e}`` an estimator name, ``gt`` for the ground truth):

    {v}/image                      EncodedImage (JPEG)
    {v}/est/{e}/keypoints          Points2D of the matches, coloured by that F's residual (SED, px) through
                                   the class ids of the static annotation context (a legend of residual bins),
                                   with per-point ``residual_px``, ``inlier`` and ``match_id``
    {v}/est/{e}/epilines           LineStrips2D: epipolar lines of N sampled matches, clipped to the image,
                                   each the colour of its point (lines in a come from F^T x_b, in b from F x_a)
    {v}/epipoles                   Points2D, one per F, labelled (+ Arrows2D towards those outside the image
                                   or at infinity, marked at the border)
    plots/residuals/{e}            BarChart: SED per evaluation match (px), sorted
    plots/histogram/{e}            BarChart: histogram of SED over all matches (bins of HIST_BIN_PX)
    metrics/{metric}               Scalars on the ``pair`` timeline, one series per F (named by SeriesLines)
    errors/{e}                     TextLog: why an estimator failed on this pair
    summary                        TextDocument (Markdown): pair, F matrices, metrics table
    pair/info                      TextDocument: the pair's name (what ``fviz summary`` lists)

Every pair sits at one index of the ``pair`` timeline (``inspect`` writes index 0; ``eval`` one per pair).
"""

from __future__ import annotations


import numpy as np

TIMELINE = "pair"
VIEWS = ("a", "b")
HIST_BIN_PX = 0.25
HIST_BINS = 40  # 0 .. 10 px, the last bin also holds everything above
RESIDUAL_RED_PX = 3.0  # residual colour saturates to red here
GT_LINE_COLOR = (255, 255, 255, 160)


def image(view: str) -> str:
    return f"{view}/image"


def est(view: str, name: str, what: str) -> str:
    """what: keypoints | epilines | epipole."""
    return f"{view}/est/{name}/{what}"


def residual_plot(name: str) -> str:
    return f"plots/residuals/{name}"


def histogram_plot(name: str) -> str:
    return f"plots/histogram/{name}"


def metric(key: str) -> str:
    return f"metrics/{key}"


def epipoles(view: str) -> str:
    return f"{view}/epipoles"


def error(name: str) -> str:
    return f"errors/{name}"


SUMMARY = "summary"
PAIR_INFO = "pair/info"


RESIDUAL_BIN_PX = 0.25
RESIDUAL_CLASSES = int(RESIDUAL_RED_PX / RESIDUAL_BIN_PX) + 1  # the last class: >= RESIDUAL_RED_PX


def residual_classes(residual_px: np.ndarray) -> np.ndarray:
    """Residual (px) -> class id of its bin (0 .. RESIDUAL_CLASSES - 1); NaN -> the last.  (N,) -> (N,) uint16."""
    r = np.nan_to_num(np.asarray(residual_px, float), nan=np.inf)
    return np.minimum(r / RESIDUAL_BIN_PX, RESIDUAL_CLASSES - 1).astype(np.uint16)


def class_color(cls: int | np.ndarray) -> np.ndarray:
    """Green (0 px) -> yellow (RESIDUAL_RED_PX / 2) -> red (>= RESIDUAL_RED_PX).  -> (..., 3) uint8."""
    r = np.asarray(cls, float) / (RESIDUAL_CLASSES - 1)
    return (np.stack([np.clip(2 * r, 0, 1), np.clip(2 - 2 * r, 0, 1), np.zeros_like(r)], -1) * 255).astype(np.uint8)


def annotation_context():
    """The legend: one class per residual bin, coloured and labelled."""
    import rerun as rr

    infos = []
    for c in range(RESIDUAL_CLASSES):
        lo = c * RESIDUAL_BIN_PX
        label = f">= {lo:g} px" if c == RESIDUAL_CLASSES - 1 else f"{lo:g}-{lo + RESIDUAL_BIN_PX:g} px"
        infos.append(rr.AnnotationInfo(id=c, label=label, color=tuple(int(v) for v in class_color(c))))
    return rr.AnnotationContext(infos)


def blueprint(size_a: tuple[int, int], size_b: tuple[int, int]):
    """Image a | image b (all estimators; toggle them in the view's entity tree), then residual bar charts,
    histograms, metric series and the Markdown summary."""
    import rerun.blueprint as rrb

    def view(v: str, size: tuple[int, int]):
        w, h = size
        return rrb.Spatial2DView(
            origin=v, name=f"image {v}", visual_bounds=rrb.VisualBounds2D(x_range=[-0.5, w - 0.5], y_range=[-0.5, h - 0.5])
        )

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(view("a", size_a), view("b", size_b)),
            rrb.Horizontal(
                rrb.BarChartView(origin="plots/residuals", name="residual per evaluation match (px)"),
                rrb.BarChartView(origin="plots/histogram", name=f"residual histogram ({HIST_BIN_PX:g} px bins)"),
                rrb.TimeSeriesView(origin="metrics", name="metrics"),
                rrb.TextDocumentView(origin=SUMMARY, name="summary"),
                column_shares=[2, 2, 2, 3],
            ),
            row_shares=[3, 2],
        ),
        collapse_panels=True,
    )
