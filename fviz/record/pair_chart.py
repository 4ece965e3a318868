"""One pair's comparison chart on the overview: per metric a bar per F on a log scale (or, without ground truth,
the estimators' agreement matrix), and the CDF of each F's residuals over the evaluation matches."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fviz.evaluate import PairResult
from fviz.geometry import NSGD_RECALL_THRESHOLD
from fviz.record import layout as L
from fviz.record.charts import BAR_HEAD, BAR_LABEL_X, BAR_PITCH, BAR_WIDTH, CDF_H, COMPARED_METRICS, LABEL_DROP, MATRIX_NAMES_W
from fviz.record.marks import Colors, rgb
from fviz.stats import fmt
from fviz.record.run_plots import cumulative_curve


def bar_lengths(values: Sequence[float], width: float) -> np.ndarray:
    """Bar lengths on a log scale, so that 0.17 and 0.21 px part beside 7.1: the largest value fills
    ``width``, a decade below the smallest positive one (or 1 % of the largest) starts at 0; zero, negative and
    missing values get no bar. (N,) -> (N,)."""
    v = np.asarray(values, float)
    pos = v[np.isfinite(v) & (v > 0)]
    if not len(pos):
        return np.zeros(len(v))
    hi = float(pos.max())
    lo = min(float(pos.min()) / 10, hi / 100)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = width * (np.log10(v) - np.log10(lo)) / (np.log10(hi) - np.log10(lo))
    return np.where(np.isfinite(v) & (v > 0), out, 0.0)


# Per-point residual CDF on the overview's chart: share of the evaluation matches within x px of each F's lines.
RESIDUAL_CDF_PX = np.geomspace(0.01, 10.0, 41)


def log_comparison(rec, result: PairResult, colors: Colors) -> None:
    """The overview's chart, drawn in 2D (y down): per metric a title and one horizontal bar per F in its
    colour on a log scale (:func:`bar_lengths`), each labelled "name value" just right of its bar; below, the
    CDF of each F's residuals (SED) over the evaluation matches (log x)."""
    import rerun as rr

    width, pitch, head = BAR_WIDTH, BAR_PITCH, BAR_HEAD
    bars, bar_colors, bar_radii, points, labels = [], [], [], [], []
    y = 0.0
    for key, title in COMPARED_METRICS:
        values = [np.nan if r.error else float(r.metrics.get(key, np.nan)) for r in result.estimators]
        if not any(np.isfinite(values)):
            continue
        if key == "agreement_nsgd" and result.agreement:
            y = _agreement_matrix(result.agreement, title, y, bars, bar_colors, bar_radii, points, labels)
            continue
        points.append((width / 2, y - LABEL_DROP))
        labels.append(title + " (log scale)")
        y += head
        for r, v, length in zip(result.estimators, values, bar_lengths(values, width)):
            if r.name == L.GT and v == 0:
                continue  # the ground truth's own pose error and NSGD: zero by definition
            bars.append([(0.0, y), (max(length, 0.5), y)])
            bar_colors.append(rgb(colors[r.name]))
            bar_radii.append(pitch / 3)
            text = f"{r.name}: {'error' if r.error else fmt(v)}"
            points.append((max(length, 0.5) + 12.0 + 4.2 * len(text), y - LABEL_DROP))  # centred on its point
            labels.append(text)
            y += pitch
        y += pitch / 2
    y0 = y + head  # the residual CDF panel
    ok = [r for r in result.estimators if not r.error and r.residuals_px is not None and result.eval_mask is not None]
    u = np.log10(RESIDUAL_CDF_PX)
    px = width * (u - u[0]) / (u[-1] - u[0])
    for r in ok:
        recall = cumulative_curve(r.residuals_px[result.eval_mask], RESIDUAL_CDF_PX)
        bars.append(np.stack([px, y0 + CDF_H * (1 - recall)], -1))
        bar_colors.append(rgb(colors[r.name]))
        bar_radii.append(1.5)
    if ok:
        bars.append([(0.0, y0), (0.0, y0 + CDF_H), (width, y0 + CDF_H)])
        bar_colors.append(rgb((200, 200, 200)))
        bar_radii.append(0.6)
        points += [(x, y - LABEL_DROP) for x, y in ((width / 2, y0 - 16.0), (0.0, y0 + CDF_H + 14.0),
                   (width * 2 / 3, y0 + CDF_H + 14.0), (width, y0 + CDF_H + 14.0), (-30.0, y0), (-30.0, y0 + CDF_H))]
        labels += ["matches with SED < x (per F)", "0.01", "1 px", "10", "100%", "0"]
    # labels white: Rerun draws them on grey boxes, where coloured text is hard to read; the bar beside each
    # label carries the colour
    rec.log(L.COMPARE, rr.LineStrips2D(bars, colors=bar_colors, radii=bar_radii),
            rr.Points2D(points, radii=0.1, colors=[(255, 255, 255)], labels=labels, show_labels=True))


def _agreement_matrix(ag: dict, title: str, y: float, bars: list, bar_colors: list, bar_radii: list, points: list,
                      labels: list) -> float:
    """The comparison chart's agreement matrix (no ground truth), appended to its strips and labels from ``y``
    down: a cell per two estimators with their NSGD, green where they agree (< the threshold), red where not.
    -> the y below it."""
    names, m = ag["names"], np.asarray(ag["matrix"], float)
    pitch, x0 = BAR_PITCH, MATRIX_NAMES_W
    cell = min(100.0, (BAR_LABEL_X + 80.0 - x0) / len(names))
    points.append(((BAR_LABEL_X + 90.0 - 2 * pitch) / 2, y - LABEL_DROP))  # the middle of the chart's view
    labels.append(title)
    y += BAR_HEAD
    for j, name in enumerate(names):  # the column names
        points.append((x0 + (j + 0.5) * cell, y - LABEL_DROP))
        labels.append(name)
    for i, name in enumerate(names):
        y += pitch
        points.append((x0 / 2, y - LABEL_DROP))
        labels.append(name)
        for j in range(len(names)):
            bars.append([(x0 + j * cell + 6.0, y), (x0 + (j + 1) * cell - 6.0, y)])
            agree = m[i, j] < ag.get("threshold", NSGD_RECALL_THRESHOLD)
            bar_colors.append(rgb(L.SAME_COLOR if i == j else L.AGREE_COLOR if agree else L.DIFFER_COLOR))
            bar_radii.append(0.45 * pitch)
            if i != j:
                points.append((x0 + (j + 0.5) * cell, y - LABEL_DROP))
                labels.append(fmt(m[i, j], 2))
    return y + 1.5 * pitch
