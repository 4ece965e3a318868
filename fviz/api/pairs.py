"""Pairs from Python: load a pair, evaluate estimators and your own F on it, log the result or a training step to Rerun.

Every public name here is re-exported by :mod:`fviz.api` and ``import fviz``::

    import fviz, rerun as rr

    pair = fviz.pair_from_images(img_a, img_b, K=K, F_gt=F_true)         # or fviz.load_pair(kitti_root, ...)
    result = fviz.inspect_pair(pair, ("magsac",), F={"mine": F})      # a PairResult (= inspect --json)
    fviz.save_recording("pair.rrd", pair, result)                        # or fviz.log_result(rec, pair, result)

    rec = rr.RecordingStream("my-training")                              # a training loop, every N steps:
    fviz.log_training_step(rec, step, val_pairs, F_pred)                 # lines converging on the "step" timeline

Conventions: pixel coordinates with the origin at the centre of the top-left pixel (OpenCV's),
``x_b^T F x_a = 0`` (a = the first image), F of shape (3, 3) in pixels of the images given.
Bad input raises :class:`fviz.errors.FvizError` with a one-line message naming the argument.
``fviz inspect pair`` is a client of these functions.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from fviz.api.names import python_errors
from fviz.api.sources import KITTI_ROOT_ENV
from fviz.data.arrays import checked_matrix, pair_from_images
from fviz.data.pair import Pair
from fviz.errors import FvizError
from fviz.estimators.options import MAX_KEYPOINTS  # noqa: F401 (max_keypoints' range: the command line checks it)
from fviz.record.training import WATCH_POINTS, log_training_step, stream, watch_points

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr

    from fviz.evaluate import PairResult

__all__ = ["Pair", "PairResult", "load_pair", "pair_from_images", "inspect_pair", "log_result", "save_recording",
           "log_training_step", "watch_points", "WATCH_POINTS"]

DEFAULT_ESTIMATORS = ("8point", "ransac", "magsac")  # fviz.estimators.registry.DEFAULT_ESTIMATORS (checked in tests)


def threshold_specs(names: Sequence[str], threshold: float | Sequence[float] | str) -> tuple[tuple[str, ...], float]:
    """(estimator names, the robust estimators' threshold in px) of a threshold: a number; a list of them or "sweep"
    (0.25, 0.5, 1, 2, 4) runs each robust estimator at every value and its per-pair oracle (NAME@T, NAME@oracle)."""
    from fviz.estimators.sweep import parse_threshold, sweep_specs

    text = threshold if isinstance(threshold, str) else str(threshold) if isinstance(threshold, (int, float)) \
        else ",".join(str(v) for v in threshold)
    value, grid = parse_threshold(text)
    return (sweep_specs(names, grid) if grid else tuple(names)), value


def __getattr__(name: str):
    if name == "PairResult":  # the result type, without importing the evaluation at import time
        from fviz.evaluate import PairResult

        return PairResult
    raise AttributeError(name)


# ---------------------------------------------------------------------------------------------- pairs


@python_errors
def load_pair(
    kitti_root: str | Path | None = None,
    *,
    sequence: str | None = None,
    drive: str | None = None,
    frame: int = 0,
    kind: str = "stereo",
    step: int = 1,
    cams: tuple[int, int] | None = None,
    synthetic: bool = False,
    seed: int = 0,
    image_a: str | Path | None = None,
    image_b: str | Path | None = None,
    K: str | None = None,
    K_a: str | None = None,
    K_b: str | None = None,
    T_ab: str | None = None,
    F_gt: str | None = None,
    pairs: str | Path | None = None,
    images: str | Path | None = None,
    index: int | None = None,
    colmap: str | Path | None = None,
    min_shared: int = 100,
    matches: str | Path | None = None,
    gt_matches: str | Path | None = None,
) -> Pair:
    """Load one pair, with its ground truth when the source knows it, from any source fviz reads.

    Sources (the first that applies):

    - two image files ``image_a``, ``image_b`` with, optionally, intrinsics ``K`` (both) or ``K_a``/``K_b``
      ("fx,fy,cx,cy" or 9 numbers, or a file of them), a relative pose ``T_ab`` (12 or 16 numbers, x_b = R x_a + t)
      or ``F_gt`` (9 numbers). For arrays and numeric matrices use :func:`pair_from_images`;
    - a pairs file ``pairs`` (SuperGlue / LightGlue layout, images under ``images``) or a COLMAP model ``colmap``:
      the pair at line / pair ``index`` (from 0), or named by ``image_a`` and ``image_b``;
    - ``synthetic=True``: a synthetic KITTI-like scene of ``seed`` (exact ground truth, no dataset needed);
    - KITTI under ``kitti_root`` (default ``$FVIZ_KITTI_ROOT``): odometry ``sequence`` (e.g. "00") or raw
      ``drive``, image a at ``frame``; ``kind`` "stereo" (cameras ``cams``, default 0 and 1) or "temporal"
      (frame + ``step``).

    ``matches`` (hloc h5, SuperGlue npz, text) replaces fviz's own features with yours; ``gt_matches`` are
    ground-truth correspondences the metrics are computed on.

    Returns:
        The :class:`Pair`: ``image_a``, ``image_b`` (H, W) or (H, W, 3) uint8; ``K_a``, ``K_b`` (3, 3), ``R`` (3, 3),
        ``t`` (3,), ``F_gt`` (3, 3) unit norm, each None when unknown.

    Example:
        >>> pair = fviz.load_pair("data/kitti", sequence="00", frame=0, kind="temporal")  # doctest: +SKIP
    """
    if any(v is not None for v in (image_a, image_b, pairs, colmap)):  # one source: a KITTI flag beside it is refused
        kitti = {"--kitti-root": kitti_root, "--sequence": sequence, "--drive": drive, "--cams": cams,
                 "--synthetic": synthetic or None}
        if given := [flag for flag, v in kitti.items() if v is not None]:
            from fviz.data.selection import user_source_conflict

            raise FvizError(f"{given[0]}: {user_source_conflict(pairs, colmap)}")
    p = _user_pair(dict(image_a=image_a, image_b=image_b, K=K, K_a=K_a, K_b=K_b, T_ab=T_ab, F_gt=F_gt, pairs=pairs,
                        images=images, index=index, colmap=colmap, min_shared=min_shared))
    if p is None:
        p = _kitti_or_synthetic(kitti_root, sequence, drive, frame, kind, step, cams, synthetic, seed)
    if matches or gt_matches:
        from fviz.api.sources import with_matches

        p = with_matches(p, matches or None, gt_matches=gt_matches or None)
    return p


def _user_pair(user: dict) -> Pair | None:
    """The pair of image_a/image_b, or pair ``index`` of a pairs file or COLMAP model; else None."""
    images = user["image_a"] is not None or user["image_b"] is not None
    listed = user["pairs"] is not None or user["colmap"] is not None
    names = None
    if images and listed:  # the pair of a list, by its images' names
        if user["image_a"] is None or user["image_b"] is None or user["index"] is not None:
            raise FvizError("--pairs/--colmap: pick a pair by --index N or by both names (--image-a NAME --image-b NAME)")
        names, images = (str(user["image_a"]), str(user["image_b"])), False
    gt_flags = [f for f, k in (("--K", "K"), ("--K-a", "K_a"), ("--K-b", "K_b"), ("--T-ab", "T_ab"), ("--F-gt", "F_gt")) if user[k]]
    if gt_flags and (not images or names):
        raise FvizError(f"{gt_flags[0]}: only with --image-a and --image-b (a pairs file or model has its own ground truth)")
    if images:
        if user["image_a"] is None or user["image_b"] is None:
            raise FvizError(f"--image-{'a' if user['image_a'] is None else 'b'}: missing (give both images)")
        from fviz.data.images import two_images

        return two_images(str(user["image_a"]), str(user["image_b"]), user["K"], user["K_a"], user["K_b"], user["T_ab"],
                          user["F_gt"])
    if not listed:
        if user["index"] is not None:
            raise FvizError("--index: only with --pairs or --colmap")
        return None
    from fviz.data.sources import user_source

    source = user_source(user["pairs"], user["images"], user["colmap"], user["min_shared"])
    return source.load(source.pair_id(source.index_of(user["index"], names)))


def _kitti_or_synthetic(kitti_root, sequence, drive, frame, kind, step, cams, synthetic: bool, seed: int) -> Pair:
    from fviz.api.sources import KINDS, kitti_pair, synthetic_pair
    from fviz.errors import from_command_line

    if kind not in KINDS:
        raise FvizError(f"{'--pair' if from_command_line() else 'kind'} {kind!r}: choose one of {', '.join(KINDS)}")
    if synthetic:
        return synthetic_pair(seed, kind=kind)
    root = kitti_root or os.environ.get(KITTI_ROOT_ENV)
    if not root:
        raise FvizError(f"--kitti-root: missing (or set ${KITTI_ROOT_ENV}); use --synthetic for a scene that needs no dataset")
    return kitti_pair(root, sequence=sequence, drive=drive, frame=frame, kind=kind, step=step,
                      cams=None if cams is None else tuple(cams))

# ---------------------------------------------------------------------------------------------- evaluation


def inspect_pair(
    pair: Pair,
    estimators: Sequence[str | tuple[str, Any]] = DEFAULT_ESTIMATORS,
    F: Mapping[str, Any] | None = None,
    *,
    features: str = "sift",
    max_keypoints: int = 2000,
    ratio: float = 0.8,
    mutual: bool = True,
    threshold: float = 1.0,
    confidence: float = 0.999,
    max_iters: int = 10000,
    seed: int = 0,
    norm: str = "fbn",
    eval_threshold: float = 2.0,
    timeout: float = 600.0,
) -> PairResult:
    """Run estimators on a pair and score them, and your own F matrices, with the paper's protocol: what
    ``fviz inspect pair`` computes (named after it: ``fviz.evaluate`` is the protocol's module).

    Args:
        pair: a :class:`Pair` (:func:`load_pair`, :func:`pair_from_images`).
        estimators: estimator names fviz knows ("8point", "ransac", "magsac", "lmeds", "poselib", "deep:PATH",
            "module:function", ...) or ``(name, function)`` pairs, ``function(pair, x_a, x_b) -> F`` or
            ``(F, inlier_mask)`` with x_a, x_b (M, 2) matched pixels; ``()`` for none.
        F: your matrices, ``{"mine": F}`` with F (3, 3) of rank 2 in pixels (x_b^T F x_a = 0; numpy or torch). Each
            becomes a row scored exactly as an estimator's (inliers: Sampson distance below ``threshold``). A rank-3
            matrix is refused (it has no epipoles): project it to rank 2 yourself if that is what you mean.
        features: "sift", "orb" or "akaze" (fviz's own; ignored when the pair carries your matches).
        max_keypoints: keypoints per image.
        ratio: Lowe's ratio test of the matcher.
        mutual: keep mutual nearest neighbours only.
        threshold: inlier threshold of the robust estimators (px); also the inliers of your F (Sampson distance).
        confidence: robust estimators' confidence.
        max_iters: robust estimators' iteration cap.
        seed: robust estimators' random seed.
        norm: the normalization of EPI-ABS / EPI-SQR: "fbn", "abs" or "etr".
        eval_threshold: evaluation matches are within this symmetric epipolar distance of F_gt (px).
        timeout: seconds one estimator may take; past it, it fails (its row holds the error).

    Returns:
        A :class:`fviz.evaluate.PairResult`: ``estimators`` (one ``EstimatorResult`` per F: ``name``, ``F`` (3, 3),
        ``metrics`` dict, ``error``), the ground truth's row ``gt`` first when known (without it, a threshold sweep's
        per-pair oracle is left out, with a note), ``verdict`` (``kind``, ``text``:
        the pair's verdict, :mod:`fviz.verdicts`); ``to_dict()`` is exactly
        what ``fviz inspect pair --json`` prints (without its ``recording`` key).
    """
    from fviz.estimators.base import missing_K
    from fviz.estimators.options import EstimatorOptions
    from fviz.estimators.sweep import ORACLE_SUFFIX
    from fviz.evaluate import GT_NAME, evaluate_pair
    from fviz.geometry import NORMS

    if not isinstance(pair, Pair):
        raise FvizError(f"pair: expected an fviz.Pair, got {type(pair).__name__}")
    if isinstance(estimators, str):
        estimators = (estimators,)
    given = [e for e in estimators if not isinstance(e, str)]
    if any(not (isinstance(e, tuple) and len(e) == 2 and isinstance(e[0], str) and callable(e[1])) for e in given):
        raise FvizError("estimators: expected names or (name, function) pairs")
    opts = EstimatorOptions(tuple(e for e in estimators if isinstance(e, str)), features, max_keypoints, ratio, mutual,
                            threshold, confidence, max_iters, seed)
    resolved = opts.estimators() if opts.names else []
    named = iter(resolved)
    ests = [next(named) if isinstance(e, str) else e for e in estimators]
    if len({n for n, _ in ests}) != len(ests):
        raise FvizError(f"estimators: repeated name in {', '.join(n for n, _ in ests)}")
    if F is not None and not isinstance(F, Mapping):
        shape = getattr(F, "shape", None)
        raise FvizError(f"F: expected a dict of your matrices by name, {{\"mine\": F}}, got {type(F).__name__}"
                        + (f" of shape {tuple(shape)}" if shape is not None else "") + " (write F={\"mine\": F})")
    from fviz.data.images import check_rank2

    for name, given in (F or {}).items():
        if not isinstance(name, str) or not name or "/" in name:
            raise FvizError(f"F: key {name!r} is not a name (a non-empty string without '/')")
        if name == GT_NAME or name in {n for n, _ in ests}:
            raise FvizError(f"F[{name!r}]: the name is taken (by {'the ground truth' if name == GT_NAME else 'an estimator'})")
        m = checked_matrix(given, f"F[{name!r}]")
        if not np.abs(m).max() > 0:
            raise FvizError(f"F[{name!r}]: all zero")
        check_rank2(m / np.abs(m).max(), f"F[{name!r}]")
        ests.append((name, _given(m)))
    notes = []
    if not pair.has_gt and (oracles := [n for n, _ in ests if n.endswith(ORACLE_SUFFIX)]):
        ests = [(n, fn) for n, fn in ests if n not in oracles]
        notes.append(f"{', '.join(oracles)} left out: a per-pair oracle keeps the threshold whose F is closest to the "
                     "ground truth, and this pair has none")
    if (why := next((w for n, fn in ests if (w := missing_K(n, fn, pair))), None)) is not None:
        raise FvizError(why)
    if norm not in NORMS:
        raise FvizError(f"norm {norm!r}: choose one of {', '.join(NORMS)}")
    specs = dict(zip([n for n, _ in resolved], opts.names))
    inspected = Inspected(ests, specs, opts, norm, eval_threshold, threshold, timeout, notes)
    return judged(pair, inspected, evaluate_pair(pair, ests, opts.feature_config(), norm, eval_threshold, threshold,
                                                 timeout=timeout))


@dataclass(frozen=True)
class Inspected:
    """How :func:`inspect_pair` evaluated a pair (kept on its result, ``_inspected``): the estimators resolved
    (``ests``: [(name, fn)]; ``specs``: a built-in's name -> its spec, to resolve it again with other settings), the
    options and the notes it added. :func:`fviz.reestimate` evaluates an edit of the matches the same way."""

    ests: list
    specs: dict
    options: Any
    norm: str
    eval_threshold: float
    threshold: float
    timeout: float
    notes: list


def judged(pair: Pair, inspected: Inspected, result: PairResult) -> PairResult:
    """``result`` with inspect's notes, the ground-truth check and the verdict; tied to ``pair``."""
    from fviz.diagnose import gt_suspect_note
    from fviz.verdicts import verdict_of

    result.notes[:0] = inspected.notes
    if (note := gt_suspect_note(pair, result)) is not None:
        result.notes.insert(0, note)
    result.verdict = verdict_of(pair, result)
    result._of_pair = pair_fingerprint(pair)  # log_result / save_recording check they are given this pair
    result._inspected = inspected
    return result


def pair_fingerprint(pair: Pair) -> tuple:
    """(name, sizes, digest of the pixels and the ground truth) of a pair: what ties a result to its pair."""
    from fviz.digest import array_digest

    return (pair.id.name, tuple(pair.size_a), tuple(pair.size_b),
            array_digest(*(a for a in (pair.image_a, pair.image_b, pair.F_gt) if a is not None)))


def check_result_of(pair: Pair, result: Any) -> None:
    """A one-line error when ``result`` was not computed on ``pair`` (its name, image sizes or, for a result of
    :func:`inspect_pair`, pixels and ground truth differ): its F's would be drawn over another pair's images."""
    from fviz.evaluate import PairResult

    if not isinstance(pair, Pair):
        raise FvizError(f"pair: expected an fviz.Pair, got {type(pair).__name__}")
    if not isinstance(result, PairResult):
        raise FvizError(f"result: expected the PairResult of fviz.inspect_pair, got {type(result).__name__}")
    got = (result.pair.get("name"), tuple(result.pair.get("size_a") or ()), tuple(result.pair.get("size_b") or ()))
    have = (pair.id.name, tuple(pair.size_a), tuple(pair.size_b))
    if got != have:
        size = lambda t: f"{t[1][0]}x{t[1][1]} and {t[2][0]}x{t[2][1]}" if len(t[1]) == len(t[2]) == 2 else "?"  # noqa: E731
        raise FvizError(f"result: computed on the pair {got[0]} ({size(got)}), not on this pair {have[0]} ({size(have)}): "
                        "give each pair its own inspect_pair result")
    mark = getattr(result, "_of_pair", None)
    if mark is not None and mark != pair_fingerprint(pair):
        raise FvizError(f"result: computed on another pair named {have[0]} (other pixels or ground truth): give each "
                        "pair its own inspect_pair result")


def _given(F: np.ndarray):
    """An estimator returning the caller's F (no inlier mask: scored like any estimator's)."""

    def given(pair, x_a, x_b):
        return F.copy()

    return given


# ---------------------------------------------------------------------------------------------- recording

def log_result(rec: rr.RecordingStream | None, pair: Pair, result: PairResult, *, lines: int = 30, probe: int = 20,
               probe_by: str | None = None, index: int = 0, blueprint: bool = True) -> None:
    """Log an evaluated pair into your Rerun recording, with fviz's layout (:mod:`fviz.record.layout`).

    Args:
        rec: a ``rerun.RecordingStream`` you own: saving to an ``.rrd``, connected to a viewer, or shown in a
            notebook (``rec.notebook_show()``); None: the global one of ``rr.init``.
        pair: the pair.
        result: its :func:`inspect_pair` result.
        lines: epipolar lines drawn per F (a fixed subset of the evaluation matches).
        probe: steps of the ``probe`` timeline (the worst evaluation matches, one per step).
        probe_by: order the probe by this estimator's residual (default: the largest over the estimators).
        index: the pair's position on the ``pair`` timeline. Log many pairs, of any sizes, into one recording with
            ``index=0, 1, ...``: it then behaves as ``eval --full``'s (:mod:`fviz.record.stream_pairs`): at each
            index only that pair's entities are shown (what another pair logged and this one did not is cleared),
            its lines and keypoints its own, a click answered with its F's; the layout opens on ``pair`` and
            frames the largest pair (Rerun keeps one layout per recording). The same index again replaces that pair.
        blueprint: send fviz's blueprint (``rec.send_blueprint``): an overview tab, one tab per F, the probe;
            again when a pair changes it (another size, another F).
    """
    from fviz.record.stream_pairs import log_pair_into

    rec = stream(rec)
    if lines < 0 or probe < 0:
        raise FvizError(f"{'lines' if lines < 0 else 'probe'}: must be >= 0")
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
        raise FvizError(f"index: expected an int >= 0, got {index!r}")
    check_result_of(pair, result)
    log_pair_into(rec, pair, result, lines, probe, probe_by, int(index), blueprint)


def save_recording(path: str | Path, pair: Pair, result: PairResult, *, lines: int = 30, probe: int = 20,
                   probe_by: str | None = None) -> Path:
    """Write the recording ``fviz inspect pair`` writes (``*.rrd``, blueprint stored), atomically: the file
    appears complete or not at all. Open it with ``rerun PATH`` or ``fviz open PATH``.

    Args:
        path: the ``*.rrd`` file to write (replaced when it exists).
        pair: the pair.
        result: its :func:`inspect_pair` result.
        lines: epipolar lines drawn per F.
        probe: steps of the ``probe`` timeline.
        probe_by: order the probe by this estimator's residual (default: the largest over the estimators).

    Returns:
        The path written.
    """
    from fviz.atomic import target
    from fviz.record.pair_recording import write_pair_recording

    if lines < 0 or probe < 0:
        raise FvizError(f"{'lines' if lines < 0 else 'probe'}: must be >= 0")
    check_result_of(pair, result)
    target(Path(path))  # a folder or special file: refused (the writer's one-line error)
    if Path(path).suffix != ".rrd" and not (Path(path).exists() and not Path(path).is_file()):
        raise FvizError(f"path {path}: a recording is a *.rrd file")
    return write_pair_recording(path, pair, result, lines, probe, probe_by)


# ---------------------------------------------------------------------------------------------- training
