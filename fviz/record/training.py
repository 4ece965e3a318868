"""A network's predictions on a few fixed pairs, logged into any Rerun recording at every N steps of a training
loop: :func:`log_training_step` (public as ``fviz.log_training_step``; ``fviz train`` logs its watched pairs with it)."""

from __future__ import annotations

import weakref
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from fviz.data.pair import Pair
from fviz.errors import FvizError

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr


def stream(rec):
    """``rec``, or (None) the global recording of ``rr.init``; FvizError when there is none."""
    import rerun as rr

    rec = rec if rec is not None else rr.get_global_data_recording()
    if not isinstance(rec, rr.RecordingStream):
        raise FvizError(f"rec: expected a rerun.RecordingStream (or None after rr.init), got {type(rec).__name__}")
    return rec


WATCH_POINTS = 24  # correspondences per watched pair: lines drawn and residuals taken

_shown: "weakref.WeakKeyDictionary[Any, set[str]]" = weakref.WeakKeyDictionary()  # rec -> pairs logged static


def watch_points(pair: Pair, n: int = WATCH_POINTS, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Fixed correspondences of a pair on its ground truth (x_b^T F_gt x_a = 0), as :func:`log_training_step` draws.

    The source's exact ones when it has them (synthetic scenes), else x_a uniform in image a and x_b uniform along
    F_gt x_a inside image b; the same for the same pair and ``seed``.

    Returns:
        (x_a, x_b): (n, 2) pixels each (fewer when F_gt's lines rarely cross image b).
    """
    if pair.points_a is not None and len(pair.points_a):
        k = np.random.default_rng(seed).permutation(len(pair.points_a))[:n]
        return np.asarray(pair.points_a, float)[k], np.asarray(pair.points_b, float)[k]
    from fviz.geometry import homogeneous
    from fviz.geometry.fmbench import points_on_lines

    rng = np.random.default_rng(seed)
    (wa, ha), size_b = pair.size_a, pair.size_b
    x_a = rng.random((4 * n, 2)) * [wa - 1, ha - 1]
    x_b, ok = points_on_lines(homogeneous(x_a) @ np.asarray(pair.F_gt, float).T, size_b, rng.random(4 * n))
    return x_a[ok][:n], x_b[ok][:n]


def log_training_step(rec: rr.RecordingStream | None, step: int, pairs: Sequence[Pair], F_pred: Any,
                      names: Sequence[str] | None = None, n_points: int = WATCH_POINTS, blueprint: bool = True) -> np.ndarray:
    """Log a network's predictions on a few fixed pairs at ``step``: call it every N steps of any training loop.

    Per pair (``watch/{name}``, :mod:`fviz.record.layout`): both images and the ground truth's epipolar lines and
    epipole (once per recording), and at ``step`` on the ``step`` timeline the network's lines of the same
    correspondences and its epipole, the correspondences coloured by the network's residual, and its median
    symmetric epipolar distance (the residual plot). Scrubbing ``step`` in the viewer shows the lines converge.
    The first call on a recording also sends the layout (:func:`fviz.record.layout.training_blueprint`).

    Args:
        rec: your ``rerun.RecordingStream`` (a file, a viewer, a notebook); None: the global one of ``rr.init``.
        step: the optimizer step (>= 0).
        pairs: B pairs with ground truth (:func:`pair_from_images` of your validation images and F, or
            :func:`load_pair`); the same pairs, in the same order, at every call.
        F_pred: (B, 3, 3) the network's F per pair, in pixels of the pair's images (numpy or torch).
        names: B entity names (default "0", "1", ...).
        n_points: correspondences per pair (fixed: :func:`watch_points`).
        blueprint: send the layout with the first call on ``rec`` (False: yours, or none).

    Returns:
        (B,) the network's median symmetric epipolar distance per pair (px), as logged.
    """
    import rerun as rr

    from fviz.geometry import clip_lines, epipoles, lines_in_a, lines_in_b, symmetric_epipolar_distance
    from fviz.record import layout as L
    from fviz.record.marks import epipole_marks, log_marks
    from fviz.record.placement import match_points, offset_b
    from fviz.record.writer import encode_jpeg

    rec = stream(rec)
    pairs = list(pairs)
    names = [str(i) for i in range(len(pairs))] if names is None else [str(n) for n in names]
    Fs = np.asarray(F_pred.detach().float().cpu() if hasattr(F_pred, "detach") else F_pred, dtype=np.float64)
    if Fs.shape != (len(pairs), 3, 3):
        raise FvizError(f"F_pred: expected shape ({len(pairs)}, 3, 3) for {len(pairs)} pairs, got {Fs.shape}")
    if len(names) != len(pairs) or len(set(names)) != len(names) or any(not n or "/" in n for n in names):
        raise FvizError(f"names: expected {len(pairs)} distinct names without '/', got {names}")
    if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 0:
        raise FvizError(f"step: expected an int >= 0, got {step!r}")
    for name, p in zip(names, pairs):
        if not isinstance(p, Pair) or not p.has_gt:
            raise FvizError(f"pairs[{names.index(name)}]: expected an fviz.Pair with ground truth (F_gt)")
    colors = {k: np.asarray(c, np.uint8) for k, c in L.watch_colors().items()}
    shown = _shown.setdefault(rec, set())
    if not shown:
        if blueprint:
            rec.send_blueprint(L.training_blueprint(names, [(p.size_a, p.size_b) for p in pairs]))
        rec.log(L.WATCH, L.annotation_context(), static=True)
    rec.set_time(L.TRAIN_TIMELINE, sequence=int(step))
    out = np.full(len(pairs), np.nan)
    for i, (name, p, F) in enumerate(zip(names, pairs, Fs)):
        x_a, x_b = watch_points(p, n_points)
        sizes = {"a": p.size_a, "b": p.size_b}
        fresh = name not in shown
        if fresh:  # the images and the ground truth once, static
            rec.log(L.watch(name, "b"), rr.Transform3D(translation=[*offset_b(p.size_a), 0.0]), static=True)
            for v, img in (("a", p.image_a), ("b", p.image_b)):
                rec.log(L.watch(name, L.image(v)), rr.EncodedImage(contents=encode_jpeg(img), media_type="image/jpeg"),
                        static=True)
        for who, M in (((L.GT, p.F_gt),) if fresh else ()) + ((L.NET, F),):
            if not np.isfinite(M).all() or not np.abs(M).max() > 0:
                continue  # a diverged network: no lines at this step
            lines = {"a": lines_in_a(M, x_b), "b": lines_in_b(M, x_a)}
            for v, e in zip(L.VIEWS, epipoles(M)):
                seg, inside = clip_lines(lines[v], *sizes[v])
                cross, label, arrow = epipole_marks("ground truth" if who == L.GT else "network", e, sizes[v])
                n = int(inside.sum())
                # one (n + 2, 2, 2) array, not a list of strips: Rerun converts it at once (4x faster)
                log_marks(rec, L.watch(name, f"{v}/{who}"), np.concatenate([seg[inside], cross]),
                          np.tile(colors[who], (n + 2, 1)), np.r_[np.full(n, 0.6), 1.5, 1.5], [""] * n + [label] * 2,
                          [] if arrow is None else [(*arrow, colors[who])], clear=who == L.NET, static=who == L.GT)
        sed = symmetric_epipolar_distance(F, x_a, x_b) if np.isfinite(F).all() and np.abs(F).max() > 0 else np.full(len(x_a), np.nan)
        rec.log(L.watch(name, "points"), rr.Points2D(match_points(x_a, x_b, p.size_a), radii=2.0,
                                                     class_ids=np.tile(L.residual_classes(sed), 2)))
        out[i] = float(np.median(sed)) if len(sed) else np.nan
        rec.log(L.watch(name, "sed_px"), rr.Scalars(out[i]))
        shown.add(name)
    return out
