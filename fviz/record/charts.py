"""Where the 2D charts' rows, bars and labels sit, in 2D units (y down): the overview's comparison of one pair
(``compare`` of :mod:`fviz.record.layout`: per metric one bar per F, the residual CDF below; no ground truth: the
agreement matrix) and a run's cumulative error curves (``curves``). Their colours are the layout's."""

from __future__ import annotations

# The overview's comparison of one pair: (metric key, title), one group of bars each, drawn in 2D units.
COMPARED_METRICS = (
    ("sed_median", "median SED (px)"),
    ("rot_err_deg", "rotation error (deg)"),
    ("trans_err_deg", "translation error (deg)"),
    ("nsgd", "NSGD (FM-Bench)"),
    ("agreement_nsgd", "NSGD between the estimators (green: < 0.05, they agree)"),  # a matrix (no ground truth)
)
GT_ONLY_METRICS = ("rot_err_deg", "trans_err_deg", "nsgd")  # need a ground truth; agreement_nsgd is without one
# one row (a title or a bar) per BAR_PITCH: Rerun's labels are ~18 screen px high, so a row must stay >= 19 px
BAR_WIDTH, BAR_PITCH, BAR_HEAD, BAR_LABEL_X = 300.0, 30.0, 30.0, 450.0
LABEL_DROP = 0.5 * BAR_PITCH  # Rerun draws a point's label below the point: the chart's label points sit this much higher
CDF_H = 70.0  # the residual CDF below the bars
MATRIX_NAMES_W = 130.0  # no ground truth: the agreement matrix's row names' column, left of the cells
CURVE_W, CURVE_H, CURVE_GAP, CURVE_PANELS = 420.0, 300.0, 150.0, 3  # the curves' panels, in 2D units (y down)


def compared_metrics(gt: bool) -> tuple[tuple[str, str], ...]:
    """The comparison chart's metrics with (``gt``) or without a ground truth."""
    return tuple((k, t) for k, t in COMPARED_METRICS if (k in GT_ONLY_METRICS) == gt or k == "sed_median")


def compare_height(n_bars: int, gt: bool = True) -> float:
    """Height of the comparison chart with the metrics of :func:`compared_metrics` and ``n_bars`` F's."""
    matrix_header = 0.0 if gt else BAR_PITCH  # without ground truth the agreement matrix has a row of column names
    return len(compared_metrics(gt)) * (BAR_HEAD + (n_bars + 0.5) * BAR_PITCH) + matrix_header + BAR_HEAD + CDF_H + 30.0


def compare_bounds(n_bars: int, gt: bool = True) -> tuple[list[float], list[float]]:
    """(x range, y range) framing the comparison chart of ``n_bars`` F's."""
    return [-2 * BAR_PITCH, BAR_LABEL_X + 90.0], [-BAR_HEAD, compare_height(n_bars, gt)]


def curves_bounds(n_series: int) -> tuple[list[float], list[float]]:
    """(x range, y range) framing the cumulative error curves' panels and their legend of ``n_series`` rows below."""
    width = CURVE_PANELS * CURVE_W + (CURVE_PANELS - 1) * CURVE_GAP
    return [-80.0, width + 20.0], [-70.0, CURVE_H + 90.0 + 24.0 * n_series]
