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

# rec -> the pairs logged static ({name}) and those given a baseline ({name}/baseline)
_shown: "weakref.WeakKeyDictionary[Any, set[str]]" = weakref.WeakKeyDictionary()


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
                      names: Sequence[str] | None = None, n_points: int = WATCH_POINTS, blueprint: bool = True,
                      F_baseline: Any = None, baseline_name: str = "constant") -> np.ndarray:
    """Log a network's predictions on a few fixed pairs at ``step``: call it every N steps of any training loop.

    Per pair (``watch/{name}``, :mod:`fviz.record.layout`): both images and the ground truth's epipolar lines and
    epipole (once per recording), and at ``step`` on the ``step`` timeline the network's lines of the same
    correspondences and its epipole, the correspondences coloured by the network's residual, and its median
    symmetric epipolar distance (the residual plot). Scrubbing ``step`` in the viewer shows the lines converge.
    With ``F_baseline`` (a constant that reads no image, e.g. the training targets' mean F) its lines, epipole and
    median SED too, beside the network's (its colour: ``layout.watch_colors``): whether the network beats it at each
    step. The F's of each step go to ``watch/{name}/fundamental``, so that a click in fviz's page draws a point's
    lines under each (:mod:`fviz.interactive`). The first call on a recording also sends the layout
    (:func:`fviz.record.layout.training_blueprint`), and the first with a baseline again (naming it).

    Args:
        rec: your ``rerun.RecordingStream`` (a file, a viewer, a notebook); None: the global one of ``rr.init``.
        step: the optimizer step (>= 0).
        pairs: B pairs with ground truth (:func:`pair_from_images` of your validation images and F, or
            :func:`load_pair`); the same pairs, in the same order, at every call.
        F_pred: (B, 3, 3) the network's F per pair, in pixels of the pair's images (numpy or torch).
        names: B entity names (default "0", "1", ...).
        n_points: correspondences per pair (fixed: :func:`watch_points`).
        blueprint: send the layout with the first call on ``rec`` (False: yours, or none).
        F_baseline: (B, 3, 3) or (3, 3) (the same for every pair) the baseline's F in pixels of each pair; None: none.
        baseline_name: its name in the plot, the labels and the clicks (not "gt" or "network").

    Returns:
        (B,) the network's median symmetric epipolar distance per pair (px), as logged.
    """
    import rerun as rr

    from fviz.record import layout as L
    from fviz.record.placement import match_points, offset_b
    from fviz.record.writer import encode_jpeg

    rec = stream(rec)
    pairs = list(pairs)
    names = [str(i) for i in range(len(pairs))] if names is None else [str(n) for n in names]
    Fs = _matrices(F_pred, len(pairs), "F_pred")
    Fb = None if F_baseline is None else _matrices(F_baseline, len(pairs), "F_baseline")
    if len(names) != len(pairs) or len(set(names)) != len(names) or any(not n or "/" in n for n in names):
        raise FvizError(f"names: expected {len(pairs)} distinct names without '/', got {names}")
    if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 0:
        raise FvizError(f"step: expected an int >= 0, got {step!r}")
    if not isinstance(baseline_name, str) or not baseline_name or baseline_name in (L.GT, L.NETWORK):
        raise FvizError(f"baseline_name: expected a name other than {L.GT!r} and {L.NETWORK!r}, got {baseline_name!r}")
    for name, p in zip(names, pairs):
        if not isinstance(p, Pair) or not p.has_gt:
            raise FvizError(f"pairs[{names.index(name)}]: expected an fviz.Pair with ground truth (F_gt)")
    colors = L.watch_colors()
    shown = _shown.setdefault(rec, set())
    new_baseline = Fb is not None and not any(s.endswith("/" + L.BASELINE) for s in shown)
    if blueprint and (not shown or new_baseline):  # again when a baseline first comes: its name in the titles
        rec.send_blueprint(L.training_blueprint(names, [(p.size_a, p.size_b) for p in pairs],
                                                baseline=None if Fb is None else baseline_name))
    if not shown:
        rec.log(L.WATCH, L.annotation_context(), static=True)
    rec.set_time(L.TRAIN_TIMELINE, sequence=int(step))
    out = np.full(len(pairs), np.nan)
    for i, (name, p) in enumerate(zip(names, pairs)):
        x_a, x_b = watch_points(p, n_points)
        if name not in shown:  # the images, the ground truth and the plot's series once, static
            rec.log(L.watch(name, "b"), rr.Transform3D(translation=[*offset_b(p.size_a), 0.0]), static=True)
            for v, img in (("a", p.image_a), ("b", p.image_b)):
                rec.log(L.watch(name, L.image(v)), rr.EncodedImage(contents=encode_jpeg(img), media_type="image/jpeg"),
                        static=True)
            _log_lines(rec, name, L.GT, p, p.F_gt, x_a, x_b, colors[L.GT], "ground truth")
            rec.log(L.watch(name, "sed_px"), rr.SeriesLines(names=[L.NETWORK], colors=[colors[L.NET]]), static=True)
        sed = _log_lines(rec, name, L.NET, p, Fs[i], x_a, x_b, colors[L.NET], L.NETWORK)
        rec.log(L.watch(name, "points"), rr.Points2D(match_points(x_a, x_b, p.size_a), radii=2.0,
                                                     class_ids=np.tile(L.residual_classes(sed), 2)))
        out[i] = float(np.median(sed)) if len(sed) else np.nan
        rec.log(L.watch(name, "sed_px"), rr.Scalars(out[i]))
        fs = {L.GT: p.F_gt, L.NETWORK: Fs[i]}
        marker, plot = f"{name}/{L.BASELINE}", L.watch(name, f"sed_px/{L.BASELINE}")  # marker: no "/" in a name
        if Fb is not None:
            sed_b = _log_lines(rec, name, L.BASELINE, p, Fb[i], x_a, x_b, colors[L.BASELINE], baseline_name)
            if marker not in shown:
                rec.log(plot, rr.SeriesLines(names=[baseline_name], colors=[colors[L.BASELINE]]), static=True)
                shown.add(marker)
            rec.log(plot, rr.Scalars(float(np.median(sed_b)) if len(sed_b) else np.nan))
            fs[baseline_name] = Fb[i]
        elif marker in shown:  # a step without the baseline: an earlier step's does not linger
            for v in L.VIEWS:
                rec.log(L.watch(name, f"{v}/{L.BASELINE}"), rr.Clear(recursive=False))
        _log_fundamentals(rec, name, fs, p)
        shown.add(name)
    return out


def _matrices(F: Any, n: int, what: str) -> np.ndarray:
    """``F`` (n, 3, 3) (or (3, 3) for ``F_baseline``: one for all) as float64 numpy; FvizError on another shape."""
    Fs = np.asarray(F.detach().float().cpu() if hasattr(F, "detach") else F, dtype=np.float64)
    if what == "F_baseline" and Fs.shape == (3, 3):
        Fs = np.broadcast_to(Fs, (n, 3, 3))
    if Fs.shape != (n, 3, 3):
        raise FvizError(f"{what}: expected shape ({n}, 3, 3) for {n} pairs, got {Fs.shape}")
    return Fs


def _usable(F: np.ndarray) -> bool:
    return bool(np.isfinite(F).all() and np.abs(F).max() > 0)


def _log_lines(rec, name: str, who: str, p: Pair, F: np.ndarray, x_a: np.ndarray, x_b: np.ndarray, color, label: str
               ) -> np.ndarray:
    """``watch/{name}/{v}/{who}``: F's lines of the correspondences in both images and its epipole's cross (static
    for the ground truth, else at the current step, replacing the previous). -> (n,) their SED under F (px; NaN for
    a diverged F, which draws no lines)."""
    from fviz.geometry import clip_lines, epipoles, lines_in_a, lines_in_b, symmetric_epipolar_distance
    from fviz.record import layout as L
    from fviz.record.marks import epipole_marks, log_marks

    if not _usable(F):
        return np.full(len(x_a), np.nan)
    sizes = {"a": p.size_a, "b": p.size_b}
    lines = {"a": lines_in_a(F, x_b), "b": lines_in_b(F, x_a)}
    color = np.asarray(color, np.uint8)
    for v, e in zip(L.VIEWS, epipoles(F)):
        seg, inside = clip_lines(lines[v], *sizes[v])
        cross, text, arrow = epipole_marks(label, e, sizes[v])
        n = int(inside.sum())
        # one (n + 2, 2, 2) array, not a list of strips: Rerun converts it at once (4x faster)
        log_marks(rec, L.watch(name, f"{v}/{who}"), np.concatenate([seg[inside], cross]), np.tile(color, (n + 2, 1)),
                  np.r_[np.full(n, 0.6), 1.5, 1.5], [""] * n + [text] * 2, [] if arrow is None else [(*arrow, color)],
                  clear=who != L.GT, static=who == L.GT)
    return symmetric_epipolar_distance(F, x_a, x_b)


def _log_fundamentals(rec, name: str, fs: dict[str, np.ndarray], p: Pair) -> None:
    """``watch/{name}/fundamental`` at the current step: the F's (the ground truth first; diverged ones left out)
    and the image sizes, as ``pair/fundamental`` holds them: what a click needs (:func:`fviz.record.rebuild.watch_pairs`)."""
    import rerun as rr

    from fviz.record import layout as L

    ok = {k: np.asarray(F, float) for k, F in fs.items() if _usable(np.asarray(F, float))}
    rec.log(L.watch(name, "fundamental"), rr.AnyValues(estimators=list(ok), F=np.array(list(ok.values())).reshape(-1),
                                                       size_a=np.array(p.size_a, float), size_b=np.array(p.size_b, float)))
