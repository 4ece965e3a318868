"""fviz from Python: load a pair, evaluate estimators and your own F, log the result or a training step to Rerun.

Every name here is re-exported by ``import fviz`` (lazily: ``import fviz`` stays instant)::

    import fviz, rerun as rr

    pair = fviz.pair_from_images(img_a, img_b, K=K, F_gt=F_true)         # or fviz.load_pair(kitti_root, ...)
    result = fviz.inspect_pair(pair, ("magsac",), F={"mine": F})      # a PairResult (= inspect --json)
    fviz.save_recording("pair.rrd", pair, result)                        # or fviz.log_result(rec, pair, result)

    rec = rr.RecordingStream("my-training")                              # a training loop, every N steps:
    fviz.log_training_step(rec, step, val_pairs, F_pred)                 # lines converging on the "step" timeline

Conventions: pixel coordinates with the origin at the centre of the top-left pixel (OpenCV's),
``x_b^T F x_a = 0`` (a = the first image), F of shape (3, 3) in pixels of the images given.
Bad input raises :class:`fviz.errors.FvizError` with a one-line message naming the argument.
The command line (``fviz inspect pair``, ``fviz train``) is a client of these functions.
"""

from __future__ import annotations

import os
import weakref
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from fviz.data.pair import Pair, PairId
from fviz.errors import FvizError

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr

    from fviz.evaluate import PairResult

__all__ = ["Pair", "PairResult", "load_pair", "pair_from_images", "inspect_pair", "log_result", "save_recording",
           "log_training_step"]

KITTI_ROOT_ENV = "FVIZ_KITTI_ROOT"
DEFAULT_ESTIMATORS = ("8point", "ransac", "magsac")  # fviz.estimators.registry.DEFAULT_ESTIMATORS (checked in tests)


def __getattr__(name: str):
    if name == "PairResult":  # the result type, without importing the evaluation at import time
        from fviz.evaluate import PairResult

        return PairResult
    raise AttributeError(name)


# ---------------------------------------------------------------------------------------------- pairs


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
            from fviz.run.config import user_source_conflict

            raise FvizError(f"{given[0]}: {user_source_conflict(pairs, colmap)}")
    p = _user_pair(dict(image_a=image_a, image_b=image_b, K=K, K_a=K_a, K_b=K_b, T_ab=T_ab, F_gt=F_gt, pairs=pairs,
                        images=images, index=index, colmap=colmap, min_shared=min_shared))
    if p is None:
        p = _kitti_or_synthetic(kitti_root, sequence, drive, frame, kind, step, cams, synthetic, seed)
    if matches or gt_matches:
        from fviz.data.sources import WithCorrespondences, attach

        given = WithCorrespondences(None, matches, gt_matches, n_pairs=1)
        p = attach(p, given.matches, given.gt_matches)
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
    if synthetic:
        from fviz.data.synthetic import SceneConfig, synthetic_pair

        return synthetic_pair(seed, SceneConfig(stereo=kind == "stereo"))
    from fviz.data.kitti import open_dataset

    root = kitti_root or os.environ.get(KITTI_ROOT_ENV)
    if not root:
        raise FvizError(f"--kitti-root: missing (or set ${KITTI_ROOT_ENV}); use --synthetic for a scene that needs no dataset")
    return open_dataset(Path(root), sequence, drive).pair(frame, kind, step, None if cams is None else tuple(cams))


def _as_image(image: Any, what: str, notes: list[str]) -> tuple[np.ndarray, str | None]:
    """A path or an array -> ((H, W) or (H, W, 3) uint8, the path or None); what was changed is added to ``notes``.

    Arrays: uint8 as they are; floats within [0, 1] times 255; other values within [0, 255] (floats, wider integers)
    taken as 8-bit levels (rounded); uint16 (a 16-bit PNG read with IMREAD_UNCHANGED) and other non-negative values
    scaled by the image's largest value to 0..255, as a 16-bit PNG file is (:func:`fviz.data.images.read_user_image`);
    negative values stretched from [min, max] to [0, 255]. Each change of range is a note."""
    if isinstance(image, (str, Path)):
        from fviz.data.images import read_user_image

        return read_user_image(image, what, notes), str(image)
    try:
        a = np.asarray(image.detach().cpu() if hasattr(image, "detach") else image)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise FvizError(f"{what}: not an image array or a path ({type(image).__name__}: {exc})") from None
    if a.ndim == 3 and a.shape[0] in (1, 3) and a.shape[2] not in (1, 3):  # (C, H, W), torch's layout
        a = np.moveaxis(a, 0, -1)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != 3) or min(a.shape[:2]) < 2:
        raise FvizError(f"{what}: expected a (H, W) or (H, W, 3) image, got shape {a.shape}")
    if a.dtype != np.uint8:
        if a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
            raise FvizError(f"{what}: expected uint8 or real numbers, got {a.dtype}")
        if not np.isfinite(a).all():
            raise FvizError(f"{what}: has NaN or infinite values ({a.dtype})")
        a = _to_uint8(a, what, notes)
    return np.ascontiguousarray(a), None


def _to_uint8(a: np.ndarray, what: str, notes: list[str]) -> np.ndarray:
    """The range rule of :func:`_as_image` for an array that is not uint8 (finite, real)."""
    lo, hi = float(a.min()), float(a.max())
    floating = np.issubdtype(a.dtype, np.floating)
    if floating and lo >= 0 and hi <= 1:
        return (a.astype(np.float64) * 255.0).round().astype(np.uint8)
    if a.dtype != np.uint16 and lo >= 0 and hi <= 255:
        return a.astype(np.float64).round().astype(np.uint8)
    if lo >= 0:  # uint16 (any largest value) or values above 255
        scaled = a.astype(np.float64) * (255.0 / hi if hi > 0 else 0.0)
        notes.append(f"{what}: {a.dtype} values 0 .. {hi:g}: scaled to 8 bits by that largest value")
    else:
        scaled = (a.astype(np.float64) - lo) * (255.0 / (hi - lo) if hi > lo else 0.0)
        notes.append(f"{what}: {a.dtype} values {lo:g} .. {hi:g}: stretched to 0 .. 255 (8 bits)")
    return scaled.round().clip(0, 255).astype(np.uint8)


def _matrix(value: Any, what: str, shapes: tuple[tuple[int, ...], ...] = ((3, 3),)) -> np.ndarray | None:
    """A finite float64 array of one of ``shapes`` (None stays None); FvizError naming ``what`` otherwise."""
    if value is None:
        return None
    try:
        a = np.asarray(value.detach().cpu() if hasattr(value, "detach") else value)
        if np.iscomplexobj(a):
            raise TypeError("complex entries")
        a = a.astype(np.float64)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise FvizError(f"{what}: expected numbers, got {type(value).__name__} ({str(exc).splitlines()[0]})") from None
    if a.shape not in shapes:
        raise FvizError(f"{what}: expected shape {' or '.join(map(str, shapes))}, got {a.shape}")
    if not np.isfinite(a).all():
        raise FvizError(f"{what}: has NaN or infinite entries")
    return a


def pair_from_images(
    image_a: Any,
    image_b: Any,
    K: Any = None,
    K_a: Any = None,
    K_b: Any = None,
    R: Any = None,
    t: Any = None,
    F_gt: Any = None,
    name: str = "",
) -> Pair:
    """A pair of your two images, with whatever you know of their geometry.

    Args:
        image_a: a file path, or an array (H, W) / (H, W, 3) RGB / (3, H, W): uint8; floats in [0, 1] (times 255);
            other values in [0, 255] as 8-bit levels; uint16 and other larger values scaled by the image's largest
            value (as a 16-bit PNG is); negative values stretched from [min, max] to [0, 255]. A change of range is
            a note (``pair.notes``).
        image_b: the same for the second image.
        K: (3, 3) intrinsics of both images (or 4 numbers fx, fy, cx, cy), which must then have the same size (else
            give K_a and K_b). Needed for pose errors.
        K_a: (3, 3) intrinsics of image a (with ``K_b``), or 4 numbers fx, fy, cx, cy.
        K_b: (3, 3) intrinsics of image b.
        R: (3, 3) the rotation from camera a to b (X_b = R X_a + t); with K and t it gives the ground truth F.
        t: (3,) the translation from camera a to b (any length but 0).
        F_gt: (3, 3) ground-truth F (x_b^T F_gt x_a = 0, pixels), of rank 2, when no pose is known. May be omitted
            altogether: the estimators are then compared with each other.
        name: a label for the pair (its ``id.sequence``).

    Returns:
        The :class:`Pair` (``F_gt`` normalized to unit Frobenius norm).
    """
    from fviz.data.images import check_rank2, intrinsics, pair_of_arrays
    from fviz.geometry import is_valid, normalize

    notes: list[str] = []
    (img_a, path_a), (img_b, path_b) = _as_image(image_a, "image_a", notes), _as_image(image_b, "image_b", notes)
    if K is not None and (K_a is not None or K_b is not None):
        raise FvizError("K: sets both cameras; give K, or K_a and K_b, not both")
    Ks = {}
    for what, value in (("K_a", K if K is not None else K_a), ("K_b", K if K is not None else K_b)):
        m = _matrix(value, "K" if K is not None else what, ((3, 3), (4,)))
        Ks[what] = None if m is None else intrinsics(m.ravel(), "K" if K is not None else what)
    if (Ks["K_a"] is None) != (Ks["K_b"] is None):
        raise FvizError(f"{'K_b' if Ks['K_b'] is None else 'K_a'}: missing (give both K_a and K_b, or one K)")
    if (R is None) != (t is None):
        raise FvizError(f"{'t' if t is None else 'R'}: missing (a pose needs both R and t)")
    T_ab = None
    if R is not None:
        from fviz.data.images import pose_matrix

        T_ab = np.eye(4)
        T_ab[:3, :3], T_ab[:3, 3] = _matrix(R, "R"), _matrix(t, "t", ((3,), (3, 1))).ravel()
        T_ab = pose_matrix(T_ab.ravel(), "R")
    F = _matrix(F_gt, "F_gt")
    if F is not None:
        if not is_valid(F):
            raise FvizError("F_gt: all zero")
        F = normalize(check_rank2(F / np.abs(F).max(), "F_gt"), "fbn")
    pid = PairId("images", name, "pair", 0, 1, root=str(Path(path_a).parent) if path_a else "",
                 image_a=Path(path_a).name if path_a else "a", image_b=Path(path_b).name if path_b else "b")
    extra = {"path_a": path_a, "path_b": path_b} if path_a and path_b else {}
    return pair_of_arrays(pid, img_a, img_b, Ks["K_a"], Ks["K_b"], T_ab, F, what="R/t/F_gt", extra=extra, notes=notes,
                          shared_K="K" if K is not None else None)


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
    from fviz.diagnose import gt_suspect_note
    from fviz.estimators.base import missing_K
    from fviz.estimators.options import EstimatorOptions
    from fviz.estimators.sweep import ORACLE_SUFFIX
    from fviz.evaluate import GT_NAME, evaluate_pair
    from fviz.geometry import NORMS
    from fviz.verdicts import verdict_of

    if not isinstance(pair, Pair):
        raise FvizError(f"pair: expected an fviz.Pair, got {type(pair).__name__}")
    if isinstance(estimators, str):
        estimators = (estimators,)
    given = [e for e in estimators if not isinstance(e, str)]
    if any(not (isinstance(e, tuple) and len(e) == 2 and isinstance(e[0], str) and callable(e[1])) for e in given):
        raise FvizError("estimators: expected names or (name, function) pairs")
    opts = EstimatorOptions(tuple(e for e in estimators if isinstance(e, str)), features, max_keypoints, ratio, mutual,
                            threshold, confidence, max_iters, seed)
    named = iter(opts.estimators() if opts.names else [])
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
        m = _matrix(given, f"F[{name!r}]")
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
    result = evaluate_pair(pair, ests, opts.feature_config(), norm, eval_threshold, threshold, timeout=timeout)
    result.notes[:0] = notes
    if (note := gt_suspect_note(pair, result)) is not None:
        result.notes.insert(0, note)
    result.verdict = verdict_of(pair, result)
    result._of_pair = pair_fingerprint(pair)  # log_result / save_recording check they are given this pair
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


def _stream(rec):
    """``rec``, or (None) the global recording of ``rr.init``; FvizError when there is none."""
    import rerun as rr

    rec = rec if rec is not None else rr.get_global_data_recording()
    if not isinstance(rec, rr.RecordingStream):
        raise FvizError(f"rec: expected a rerun.RecordingStream (or None after rr.init), got {type(rec).__name__}")
    return rec


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
        index: the pair's position on the ``pair`` timeline (log several pairs into one recording).
        blueprint: send fviz's blueprint (``rec.send_blueprint``): an overview tab, one tab per F, the probe.
    """
    from fviz.record.writer import log_pair_recording, pair_blueprint

    rec = _stream(rec)
    if lines < 0 or probe < 0:
        raise FvizError(f"{'lines' if lines < 0 else 'probe'}: must be >= 0")
    check_result_of(pair, result)
    log_pair_recording(rec, pair, result, lines, probe, probe_by, index)
    if blueprint:
        rec.send_blueprint(pair_blueprint(pair, result))


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
    from fviz.record.writer import write_pair_recording

    if lines < 0 or probe < 0:
        raise FvizError(f"{'lines' if lines < 0 else 'probe'}: must be >= 0")
    check_result_of(pair, result)
    target(Path(path))  # a folder or special file: refused (the writer's one-line error)
    if Path(path).suffix != ".rrd" and not (Path(path).exists() and not Path(path).is_file()):
        raise FvizError(f"path {path}: a recording is a *.rrd file")
    return write_pair_recording(path, pair, result, lines, probe, probe_by)


# ---------------------------------------------------------------------------------------------- training

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
    from fviz.record.writer import _epipole_marks, _log_marks, encode_jpeg

    rec = _stream(rec)
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
            rec.log(L.watch(name, "b"), rr.Transform3D(translation=[*L.offset_b(p.size_a), 0.0]), static=True)
            for v, img in (("a", p.image_a), ("b", p.image_b)):
                rec.log(L.watch(name, L.image(v)), rr.EncodedImage(contents=encode_jpeg(img), media_type="image/jpeg"),
                        static=True)
        for who, M in (((L.GT, p.F_gt),) if fresh else ()) + ((L.NET, F),):
            if not np.isfinite(M).all() or not np.abs(M).max() > 0:
                continue  # a diverged network: no lines at this step
            lines = {"a": lines_in_a(M, x_b), "b": lines_in_b(M, x_a)}
            for v, e in zip(L.VIEWS, epipoles(M)):
                seg, inside = clip_lines(lines[v], *sizes[v])
                cross, label, arrow = _epipole_marks("ground truth" if who == L.GT else "network", e, sizes[v])
                n = int(inside.sum())
                # one (n + 2, 2, 2) array, not a list of strips: Rerun converts it at once (4x faster)
                _log_marks(rec, L.watch(name, f"{v}/{who}"), np.concatenate([seg[inside], cross]),
                           np.tile(colors[who], (n + 2, 1)), np.r_[np.full(n, 0.6), 1.5, 1.5], [""] * n + [label] * 2,
                           [] if arrow is None else [(*arrow, colors[who])], clear=who == L.NET, static=who == L.GT)
        sed = symmetric_epipolar_distance(F, x_a, x_b) if np.isfinite(F).all() and np.abs(F).max() > 0 else np.full(len(x_a), np.nan)
        rec.log(L.watch(name, "points"), rr.Points2D(L.match_points(x_a, x_b, p.size_a), radii=2.0,
                                                     class_ids=np.tile(L.residual_classes(sed), 2)))
        out[i] = float(np.median(sed)) if len(sed) else np.nan
        rec.log(L.watch(name, "sed_px"), rr.Scalars(out[i]))
        shown.add(name)
    return out
