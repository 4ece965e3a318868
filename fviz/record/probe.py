"""The probe of one pair: which points it walks, most telling first (:func:`probe_points`, near-duplicates skipped),
and the ``probe`` timeline that rings each in both images with its epipolar line under every F."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fviz.data.pair import Pair
from fviz.errors import FvizError
from fviz.estimators.registry import is_baseline
from fviz.evaluate import PairResult
from fviz.geometry import clip_lines, lines_in_a, lines_in_b, symmetric_epipolar_distance
from fviz.record import layout as L
from fviz.record.placement import offset_b, screen_unit
from fviz.record.marks import Colors, log_marks, names_of, rgb, ring

PROBE_STEPS = 20  # the probe's steps by default
PROBE_BY_SCORE = "score"
PROBE_SPACING_PX = 20.0  # screen px: a match this near one already walked (at either end) is a near-duplicate


@dataclass
class ProbePoints:
    """What the probe walks: points of both images (matches, or the hand-labelled correspondences of
    ``--gt-matches``), every F's residual (SED, px) on each, the indices to walk in order and why that order."""

    x_a: np.ndarray
    x_b: np.ndarray
    residuals: dict[str, np.ndarray]
    order: np.ndarray
    what: str  # "match" or "labelled correspondence"
    rank: str  # the order, in words


def _drivers(result: PairResult) -> list:
    """The estimators whose disagreement orders the probe: those fitted to the matches (never a baseline; the
    networks only when nothing else is there)."""
    from fviz.diagnose import fits_matches

    ok = [r for r in result.estimators if not r.error and r.name != L.GT and not is_baseline(r.name)]
    return [r for r in ok if fits_matches(r.name)] or ok


def probe_points(result: PairResult, by: str | None = None, gt_points=None) -> ProbePoints:
    """The probe's points and order, most telling first. ``by``: an estimator's residual, or ``score`` (the
    user's matcher's scores, least confident first). By default what the pair's question needs:
    hand-labelled correspondences (``gt_points``: (x_a, x_b)) by the ground truth's residual (a mislabelled one
    first); no evaluation match: every match by the ground truth's residual (the matcher's errors); otherwise
    the evaluation matches (every match without ground truth) by the disagreement of the estimators fitted to
    the matches and the ground truth: the largest residual minus the smallest."""
    m, ok = result.matches, [r for r in result.estimators if not r.error]
    gt = result.get(L.GT)
    gt = None if gt is None or gt.error else gt
    if gt_points is not None and gt is not None and by != PROBE_BY_SCORE:
        x_a, x_b = (np.asarray(x, float) for x in gt_points)
        residuals = {r.name: symmetric_epipolar_distance(r.F, x_a, x_b) for r in ok}
        idx, what = np.arange(len(x_a)), "labelled correspondence"
    else:
        x_a, x_b = (np.zeros((0, 2)), np.zeros((0, 2))) if m is None else (m.x_a, m.x_b)
        residuals = {r.name: r.residuals_px for r in ok}
        idx = np.flatnonzero(result.eval_mask) if result.eval_mask is not None else np.zeros(0, int)
        what = "match"
    if by == PROBE_BY_SCORE:
        scores = getattr(m, "scores", None)
        if scores is None:
            raise FvizError(f"--probe-by {by}: these matches have no scores (give --matches with the matcher's scores)")
        return ProbePoints(x_a, x_b, residuals, idx[np.argsort(scores[idx], kind="stable")], what,
                           "the matcher's score, lowest first")
    if by is not None and result.get(by) is None:
        raise FvizError(f"--probe-by {by}: not an estimator of this pair ({', '.join(names_of(result))})")
    if by is not None:
        score, rank = residuals.get(by), f"{by}'s residual"
    elif gt is not None and (what != "match" or not len(idx)):
        idx = np.arange(len(x_a))
        score = residuals[L.GT]
        rank = ("the ground truth's residual: a mislabelled correspondence first" if what != "match" else
                "the ground truth's residual over all matches (no evaluation match: the matcher's errors)")
    else:
        drivers = [r.name for r in _drivers(result)] + ([L.GT] if gt is not None else [])
        score = (np.max([residuals[n] for n in drivers], 0) - np.min([residuals[n] for n in drivers], 0)
                 if len(drivers) > 1 else residuals[drivers[0]] if drivers else None)
        rank = f"disagreement of {', '.join(drivers)} (largest residual minus smallest)"
    if score is None or not len(idx):
        return ProbePoints(x_a, x_b, residuals, idx, what, rank)
    return ProbePoints(x_a, x_b, residuals, idx[np.argsort(-np.nan_to_num(score[idx], nan=-1.0), kind="stable")], what, rank)


def spread_out(points: ProbePoints, spacing: float, steps: int) -> np.ndarray:
    """The first ``steps`` of the order, skipping near-duplicates: a point within ``spacing`` image px of one
    already taken, at either end (the same keypoint matched twice, a cluster of one structure)."""
    taken: list[int] = []
    for j in points.order:
        if len(taken) >= steps:
            break
        if not taken or min(np.linalg.norm(points.x_a[taken] - points.x_a[j], axis=1).min(),
                            np.linalg.norm(points.x_b[taken] - points.x_b[j], axis=1).min()) >= spacing:
            taken.append(int(j))
    return np.array(taken, int)


def probe_walk(pair: Pair, result: PairResult, by: str | None = None, steps: int = PROBE_STEPS) -> tuple[ProbePoints, np.ndarray]:
    """The probe's points (:func:`probe_points`) and the indices it walks: at most ``steps``, near-duplicates
    (within PROBE_SPACING_PX on screen) skipped."""
    points = probe_points(result, by, pair.gt_points)
    return points, spread_out(points, PROBE_SPACING_PX * screen_unit(pair.size_a), max(steps, 0))


def empty_probe_text(result: PairResult, steps: int, fs: list) -> str:
    """Why the probe has no step: it is off, no F gives a line, or there is no match to walk."""
    if steps <= 0:
        return "**No probe**: it is off (`--probe 0`)."
    if not fs:
        return "**No probe**: no estimator gave an F (and there is no ground truth): no epipolar line to draw."
    return f"**No probe**: {result.n_matches} matches, none to walk."


def log_probe(rec, index: int, pair: Pair, result: PairResult, steps: int = PROBE_STEPS, by: str | None = None,
              colors: Colors | None = None) -> int:
    """The ``probe`` timeline: step k rings the k-th point of :func:`probe_points` (near-duplicates skipped) in
    both images, joins them, and draws its epipolar line under every F (in a: F^T x_b, in b: F x_a) in the F's
    colour; the zoomed views follow it (``probe/zoom/{v}``); the residuals as text. -> the steps logged."""
    import rerun as rr

    colors = colors or L.estimator_colors(names_of(result))
    ok = [r for r in result.estimators if not r.error]
    points, order = probe_walk(pair, result, by, steps) if ok and steps > 0 else (None, [])
    if not len(order):  # the probe tab says why it is empty
        rec.set_time(L.PROBE_TIMELINE, sequence=0)
        rec.set_time(L.TIMELINE, sequence=index)
        rec.log(L.PROBE_TEXT, rr.TextDocument(empty_probe_text(result, steps, ok), media_type="text/markdown"))
        return 0
    unit = screen_unit(pair.size_a)
    sizes = {"a": pair.size_a, "b": pair.size_b}
    shift = offset_b(pair.size_a)
    marker = L.PROBE_COLOR
    for k, j in enumerate(order):
        rec.set_time(L.PROBE_TIMELINE, sequence=k)
        rec.set_time(L.TIMELINE, sequence=index)
        xa, xb = points.x_a[j], points.x_b[j]
        for v, lines, at in (("a", [lines_in_a(r.F, xb[None]) for r in ok], xa), ("b", [lines_in_b(r.F, xa[None]) for r in ok], xb)):
            seg, inside = clip_lines(np.concatenate(lines), *sizes[v])
            drawn = [r for r, i in zip(ok, inside) if i]
            rings = [ring(at, L.PROBE_RING_PX, 12), ring(at, L.PROBE_MARK_PX * unit, 12)]
            strips = [*seg[inside], *rings] + ([[xa, xb + shift]] if v == "a" else [])  # a's frame is the root
            # radii in UI points (negative): the same on screen in the whole images and in the zoomed views
            widths = list(-np.linspace(1.6, 0.7, len(drawn))) + [-0.8, -1.2, -0.8][: len(strips) - len(drawn)]
            log_marks(rec, L.probe(v), strips, [rgb(colors[r.name]) for r in drawn] + [marker] * (len(strips) - len(drawn)),
                      widths, [f"{r.name}: epipolar line of {points.what} {j}" for r in drawn]
                      + [f"{points.what} {j}"] * (len(strips) - len(drawn)), [], clear=False)
            rec.log(L.probe_zoom(v), rr.Transform3D.from_fields(translation=[*(at + (shift if v == "b" else 0.0)), 0.0]))
        rows = [f"| {r.name} | {points.residuals[r.name][j]:.2f} |" for r in ok]
        scores = getattr(result.matches, "scores", None) if points.what == "match" else None
        text = "\n".join([
            f"**step {k + 1} of {len(order)}**: {points.what} {j}, a ({xa[0]:.1f}, {xa[1]:.1f}) → b ({xb[0]:.1f}, {xb[1]:.1f})"
            + ("" if scores is None else f", score {scores[j]:.3g}"),
            "", "| F | SED px |", "|---|--:|", *rows, "",
            f"By {points.rank}; near-duplicates skipped. Zoomed: a line outside the {L.PROBE_RING_PX:g} px ring misses "
            "by more (summary: how to read the probe).",
        ])
        rec.log(L.PROBE_TEXT, rr.TextDocument(text, media_type="text/markdown"))
    return len(order)
