"""One pair in a recording (see :mod:`fviz.record.layout`): :func:`log_pair` logs its verdict, images, keypoints,
lines, epipoles and text at ``pair`` = index (a single pair's file, a run's or triage's); :func:`write_pair_recording`
writes ``inspect pair``'s file, the probe included."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fviz.data.pair import Pair
from fviz.evaluate import PairResult
from fviz.geometry import clip_lines, epipoles, lines_in_a, lines_in_b, symmetric_epipolar_distance
from fviz.record import layout as L
from fviz.record.placement import keypoint_radius, match_points, offset_b, screen_unit
from fviz.record.marks import (
    CROSS_PX, LINE_PX, Colors, epipole_marks, log_epipoles, log_marks, names_of, residual_scale, rgb, ring, scale_ends,
)
from fviz.record.pair_chart import log_comparison
from fviz.record.pair_text import (
    caption_strip, epipole_name_strip, log_pair_text, pair_markdown, reference_label, suspect_notice, suspect_reference,
)
from fviz.record.probe import PROBE_STEPS, log_probe, probe_points, probe_walk
from fviz.record.run_plots import log_series, log_static
from fviz.record.writer import RecordingWriter, encode_jpeg


def line_subset(result: PairResult, n: int, seed: int = 0) -> np.ndarray:
    """Indices of up to n matches for epipolar lines: evaluation matches first, a fixed random draw."""
    if result.matches is None or len(result.matches) == 0 or n <= 0:
        return np.zeros(0, int)
    pool = np.flatnonzero(result.eval_mask) if result.eval_mask.any() else np.arange(len(result.matches))
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(pool, size=min(n, len(pool)), replace=False))


def log_pair(rec, index: int, pair: Pair, result: PairResult, n_lines: int = 30, colors: Colors | None = None,
             probe_steps: int = 0, single_pair: bool = True, clear_reference: bool = False, motion: bool = True,
             by: str | None = None, many: bool = False, images: bool = True) -> None:
    """Everything of one pair at ``pair`` = index (see :mod:`fviz.record.layout`): its verdict (judged on estimator
    ``by``, default every one), images, keypoints, lines, epipoles, the summary, the metrics table, and the
    comparison chart (``single_pair``) or the metric series and (``motion``) the motion tracks (runs). The reference
    lines when the notes say the ground truth is suspect; ``clear_reference`` (a run whose pairs carry that verdict:
    triage) logs them empty otherwise. ``many``: one pair of many in a stream (as a run's: every F's matches, marks cleared).
    ``images``: False when they are logged at this index already (a redraw after an edit of the matches)."""
    import rerun as rr

    from fviz.verdicts import verdict_of

    colors = colors or L.estimator_colors(names_of(result))
    rec.set_time(L.TIMELINE, sequence=index)
    verdict = result.verdict if by is None and result.verdict is not None else verdict_of(pair, result, by)
    rec.log(L.VERDICT, rr.TextDocument(verdict.markdown(), media_type="text/markdown"))
    sizes = {"a": pair.size_a, "b": pair.size_b}
    unit = screen_unit(pair.size_a)
    rec.log("b", rr.Transform3D(translation=[*offset_b(pair.size_a), 0.0]))
    for v, img in (("a", pair.image_a), ("b", pair.image_b)) if images else ():
        rec.log(L.image(v), rr.EncodedImage(contents=encode_jpeg(img), media_type="image/jpeg"))
    log_pair_text(rec, result, pair_markdown(result, probe_steps))
    log_fundamentals(rec, result, pair.size_a, pair.size_b)
    m = result.matches
    sub = line_subset(result, n_lines)
    classes = match_classes(result)
    shared = single_pair and not many and L.GT in classes  # one pair: positions once, see layout.estimator_tab
    marks: dict[str, list] = {v: [] for v in L.VIEWS}  # every F's epipole: (name, colour, where, label, arrows)
    for r in result.estimators:
        if r.error:
            continue
        color = rgb(colors[r.name])
        if not shared or r.name == L.GT:  # else the blueprint holds its classes
            rec.log(L.matches(r.name), rr.Points2D(match_points(m.x_a, m.x_b, pair.size_a), class_ids=classes[r.name],
                                                   radii=keypoint_radius(pair.size_a),
                                                   **score_labels(m)))
        lines = {"a": lines_in_a(r.F, m.x_b[sub]), "b": lines_in_b(r.F, m.x_a[sub])}
        for v, e in zip(L.VIEWS, epipoles(r.F)):
            seg, inside = clip_lines(lines[v], *sizes[v])
            cross, label, arrow = epipole_marks(r.name, e, sizes[v], unit)
            arrows = [] if arrow is None else [(*arrow, color)]
            n = int(inside.sum())
            # lines unlabelled (hovering one names its entity, hence the estimator); the epipole's label says where
            # below image b: the estimator's numbers, or under the ground truth's lines (in every tab) the residual
            # scale; labelled strips of this entity (a Points2D would add its columns to the file)
            extra = ([] if v != "b" else residual_scale(pair.size_a, sizes[v]) if r.name == L.GT
                     else [caption_strip(pair.size_a, sizes[v], r, result)])
            shown = r.name != L.GT  # an estimator's tab names its epipole: black on a light box above the cross
            if shown:
                extra.append(epipole_name_strip(cross, label, sizes[v], unit))
            log_marks(rec, L.est(v, r.name, "epilines"), [*seg[inside], *cross, *(x[0] for x in extra)],
                      [color] * (n + 2) + [x[1] for x in extra], [LINE_PX * unit] * n + [CROSS_PX * unit] * 2 + [x[2] for x in extra],
                      [""] * n + ["" if shown else label] * 2 + [x[3] for x in extra], arrows, clear=many or not single_pair,
                      show_labels=shown)
            marks[v].append((r.name, color, cross.mean(axis=(0, 1)), label, arrows))
    for v in L.VIEWS:
        log_epipoles(rec, L.epipoles(v), marks[v], many or not single_pair, sizes[v],
                     scale_ends(pair.size_a, sizes[v]) if v == "b" else (), unit)
    if clear_reference or suspect_reference(result.notes) is not None:
        log_reference(rec, pair, result, colors, sub)
    if pair.gt_points is not None:
        log_labelled(rec, pair, result)
    if single_pair:
        log_comparison(rec, result, colors)
    else:
        log_series(rec, result, motion)


def log_labelled(rec, pair: Pair, result: PairResult) -> None:
    """``layout.LABELLED``: the hand-labelled correspondences (``--gt-matches``), both ends, coloured by the
    ground truth's residual on them; those at least RESIDUAL_MAX_PX off it ringed and labelled (a mislabel
    that F_gt, fitted to them all, could not follow)."""
    import rerun as rr

    gt = result.get(L.GT)
    if gt is None or gt.error:
        return
    x_a, x_b = (np.asarray(x, float) for x in pair.gt_points)
    residual = symmetric_epipolar_distance(gt.F, x_a, x_b)
    unit = screen_unit(pair.size_a)
    text = [f"labelled correspondence {i}: {v:.2f} px off F_gt" for i, v in enumerate(residual)]
    off = np.flatnonzero(residual >= L.RESIDUAL_MAX_PX)
    ends = match_points(x_a[off], x_b[off], pair.size_a)
    rings = [ring(p, 2.5 * L.LABELLED_RADIUS_PX * unit, 24) for p in ends]
    rec.log(L.LABELLED, rr.Points2D(match_points(x_a, x_b, pair.size_a), class_ids=np.tile(L.residual_classes(residual), 2),
                                    radii=L.LABELLED_RADIUS_PX * unit, labels=text + text, show_labels=False, draw_order=38.0),
            rr.LineStrips2D(rings, colors=[rgb(L.PROBE_COLOR)] * len(rings), radii=-1.0, labels=[text[i] for i in off] * 2,
                            show_labels=True, draw_order=39.0))


def score_labels(m) -> dict:
    """Hover text of a user's matches that carry their matcher's scores (``--matches``): both ends alike."""
    if getattr(m, "scores", None) is None:
        return {}
    text = [f"match {i}: score {v:.3g}" for i, v in enumerate(m.scores)]
    return {"labels": text + text, "show_labels": False}


def match_classes(result: PairResult) -> dict[str, np.ndarray]:
    """{estimator: class ids of ``layout.matches`` (residual bin and inlier flag, see layout.residual_classes),
    both ends of each match alike}, failed ones left out. -> (2N,) each."""
    return {r.name: np.tile(L.residual_classes(r.residuals_px, r.inliers), 2) for r in result.estimators if not r.error}


def log_fundamentals(rec, result: PairResult, size_a: tuple[int, int], size_b: tuple[int, int]) -> None:
    """``pair/fundamental``: the F's of the pair (failed estimators left out) and the image sizes, which a
    click needs (:mod:`fviz.interactive`)."""
    import rerun as rr

    ok = [r for r in result.estimators if not r.error and r.F is not None]
    rec.log(L.PAIR_FS, rr.AnyValues(estimators=[r.name for r in ok], F=np.array([r.F for r in ok], float).reshape(-1),
                                    size_a=np.array(size_a, float), size_b=np.array(size_b, float)))


def log_reference(rec, pair: Pair, result: PairResult, colors: Colors, sub: np.ndarray) -> bool:
    """``layout.REFERENCE``: when the notes name a reference F (ground truth suspect), its epipolar lines of the
    first REFERENCE_LINES line matches ``sub`` in both images, where both cross their image (image b's shifted
    below a), thick, in its colour, one label per image; otherwise empty (a run's pair: no lines linger from a
    previous one). -> whether lines were drawn."""
    import rerun as rr

    name = suspect_reference(result.notes)
    r = None if name is None else result.get(name)
    strips = []
    if r is not None and not r.error and r.F is not None:
        k = sub[: L.REFERENCE_LINES]
        seg_a, in_a = clip_lines(lines_in_a(r.F, result.matches.x_b[k]), *pair.size_a)
        seg_b, in_b = clip_lines(lines_in_b(r.F, result.matches.x_a[k]), *pair.size_b)
        both = in_a & in_b
        strips = [*seg_a[both], *(seg_b[both] + offset_b(pair.size_a))]
    n = len(strips)
    if n:  # the names: black on Rerun's light label box (text takes its strip's colour), top right of each image
        strips += [np.stack([at, at]) for at in (np.array([0.8 * pair.size_a[0], 22.0]),
                                                  np.array([0.8 * pair.size_b[0], 22.0]) + offset_b(pair.size_a))]
    colors_ = [rgb(colors[name])] * n + [rgb(L.LABEL_ON_PHOTO)] * (len(strips) - n) if n else []
    rec.log(L.REFERENCE, rr.LineStrips2D(strips, colors=colors_ or None, radii=[L.REFERENCE_RADIUS] * n + [0.0] * (len(strips) - n),
                                         labels=[""] * n + [reference_label(name)] * (len(strips) - n) or None,
                                         show_labels=True, draw_order=35.0))
    return n > 0


def pair_blueprint(pair: Pair, result: PairResult):
    """The stored layout of one pair's recording (:func:`fviz.record.layout.blueprint`, single pair)."""
    names = names_of(result)
    classes = match_classes(result)
    return L.blueprint(names, (pair.size_a, pair.size_b), single_pair=True, classes=classes if L.GT in classes else None,
                       notice=suspect_notice(result.notes), verdict=True)


def log_pair_recording(rec, pair: Pair, result: PairResult, n_lines: int = 30, probe_steps: int = PROBE_STEPS,
                       probe_by: str | None = None, index: int = 0, many: bool = False, redraw: bool = False,
                       legend: bool = True) -> int:
    """Everything ``inspect pair`` records of one pair into ``rec`` at ``pair`` = index: legend, images,
    lines, epipoles, summary, comparison, and the ``probe`` timeline (``many``: see :func:`log_pair`). ``redraw``: the
    pair is logged there already (an edit of its matches): neither its images nor the static entities again;
    ``legend`` False: no residual legend (a viewer that has it from the file). -> the probe steps."""
    colors = L.estimator_colors(names_of(result))
    steps = len(probe_walk(pair, result, probe_by, probe_steps)[1])  # checks probe_by before logging
    if not redraw:
        log_static(rec, names_of(result), legend=legend)
    rec.set_time(L.PROBE_TIMELINE, sequence=0)
    log_pair(rec, index, pair, result, n_lines, colors, steps, many=many, images=not redraw)
    log_probe(rec, index, pair, result, probe_steps, probe_by, colors)
    return steps


def write_pair_recording(path: str | Path, pair: Pair, result: PairResult, n_lines: int = 30,
                         probe_steps: int = PROBE_STEPS, probe_by: str | None = None) -> Path:
    """One pair, one file, with its blueprint stored (what ``fviz inspect pair`` writes)."""
    probe_points(result, probe_by)  # a bad --probe-by fails before any file is opened
    with RecordingWriter(path, "fviz-inspect", pair_blueprint(pair, result), index=False) as w:
        log_pair_recording(w.rec, pair, result, n_lines, probe_steps, probe_by)
    return Path(path)
