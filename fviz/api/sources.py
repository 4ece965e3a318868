"""One small constructor per source, typed (paths, numbers, arrays), each error naming its parameter::

    fviz.kitti_pair("data/kitti", sequence="00", frame=3, kind="temporal")
    fviz.synthetic_pair(seed=3, kind="temporal")                    # exact ground truth, no dataset
    fviz.pair_from_images("a.jpg", "b.jpg", K=K, R=R, t=t)          # your images (paths or arrays)
    fviz.pairs_file_pair("pairs.txt", "images/", index=0)           # SuperGlue / LightGlue layout
    fviz.colmap_pair("sparse/0", "images/", names=("a.jpg", "b.jpg"))
    fviz.with_matches(pair, "matches.h5")                           # your matches (hloc h5, npz, text)

:func:`fviz.load_pair` takes the command line's view of the same (one function, every source's flags) and calls these.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

from fviz.api.names import python_errors
from fviz.data.pair import Pair
from fviz.errors import FvizError

KITTI_ROOT_ENV = "FVIZ_KITTI_ROOT"
KINDS = ("stereo", "temporal")


def _int(value, name: str, low: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise FvizError(f"{name}: expected an int >= {low}, got {value!r}")
    return int(value)


def _kind(kind: str) -> str:
    if kind not in KINDS:
        raise FvizError(f"kind {kind!r}: 'stereo' or 'temporal'")
    return kind


def _path(value, name: str) -> Path:
    if not isinstance(value, (str, os.PathLike)):
        raise FvizError(f"{name}: expected a path, got {type(value).__name__}")
    return Path(value)


@python_errors
def kitti_pair(kitti_root: str | os.PathLike | None = None, *, sequence: str | None = None, drive: str | None = None,
               frame: int = 0, kind: str = "stereo", step: int = 1, cams: tuple[int, int] | None = None) -> Pair:
    """A KITTI pair: odometry ``sequence`` ("00") or raw ``drive`` ("2011_09_26_drive_0001_sync").

    Args:
        kitti_root: the KITTI folder (default ``$FVIZ_KITTI_ROOT``).
        sequence: an odometry sequence (poses: a few px of ground truth).
        drive: a raw drive (oxts poses: worse, and biased).
        frame: image a's frame.
        kind: "stereo" (cameras ``cams``, default 0 and 1, at ``frame``) or "temporal" (``frame`` -> ``frame + step``).
        step: frames between a and b (temporal).
        cams: the two cameras, e.g. (0, 1) or (2, 3).
    """
    from fviz.data.kitti import open_dataset

    root = kitti_root if kitti_root is not None else os.environ.get(KITTI_ROOT_ENV)
    if not root:
        raise FvizError(f"kitti_root: missing (or set ${KITTI_ROOT_ENV}); fviz.synthetic_pair needs no dataset")
    if cams is not None and (len(cams) != 2 or any(isinstance(c, bool) or not isinstance(c, int) for c in cams)):
        raise FvizError(f"cams: expected two camera numbers, e.g. (0, 1), got {cams!r}")
    frame, kind, step, root = _int(frame, "frame"), _kind(kind), _int(step, "step", 1), _path(root, "kitti_root")
    return open_dataset(root, sequence, drive).pair(frame, kind, step, None if cams is None else tuple(cams))


@python_errors
def synthetic_pair(seed: int = 0, *, kind: str = "stereo") -> Pair:
    """A synthetic KITTI-like scene (exact ground truth and correspondences; no dataset): ``kind`` "stereo" or
    "temporal" motion, ``seed`` the scene."""
    from fviz.data.synthetic import SceneConfig
    from fviz.data.synthetic import synthetic_pair as scene

    return scene(_int(seed, "seed"), SceneConfig(stereo=_kind(kind) == "stereo"))


def _which(index: int | None, names: Sequence[str] | None) -> tuple[int | None, tuple[str, str] | None]:
    if (index is None) == (names is None):
        raise FvizError("index: give the pair by index (from 0) or by names=(image_a, image_b), one of the two")
    if names is not None and (len(names) != 2 or not all(isinstance(n, str) for n in names)):
        raise FvizError(f"names: expected two image names, got {names!r}")
    return (None if index is None else _int(index, "index")), (None if names is None else tuple(names))


def _listed(source, which: tuple[int | None, tuple[str, str] | None]) -> Pair:
    return source.load(source.pair_id(source.index_of(*which)))


@python_errors
def pairs_file_pair(pairs: str | os.PathLike, images: str | os.PathLike, *, index: int | None = None,
                    names: Sequence[str] | None = None) -> Pair:
    """A pair of a pairs file (SuperGlue / LightGlue layout: ``name0 name1 [rot0 rot1 K0 K1 T_0to1]`` per line),
    its images under ``images``: the line ``index`` (from 0) or the pair ``names`` (image a, image b)."""
    from fviz.data.sources import user_source

    which = _which(index, names)
    return _listed(user_source(_path(pairs, "pairs"), _path(images, "images")), which)


@python_errors
def colmap_pair(model: str | os.PathLike, images: str | os.PathLike | None = None, *, index: int | None = None,
                names: Sequence[str] | None = None, min_shared: int = 100) -> Pair:
    """A pair of a COLMAP model (``cameras``, ``images``, ``points3D``; pixel origin converted once): pair ``index``
    (from 0, among the image pairs sharing at least ``min_shared`` points) or ``names``; images under ``images``."""
    from fviz.data.sources import user_source

    which = _which(index, names)
    source = user_source(None, None if images is None else _path(images, "images"), _path(model, "model"),
                         _int(min_shared, "min_shared", 1))
    return _listed(source, which)


@python_errors
def with_matches(pair: Pair, matches: str | os.PathLike | None = None, *,
                 gt_matches: str | os.PathLike | None = None) -> Pair:
    """``pair`` with your matches (hloc matches.h5 beside its features.h5, SuperGlue's npz, text rows
    ``x_a y_a x_b y_b [score]``) used instead of fviz's features, and/or hand-labelled ground-truth correspondences
    (``gt_matches``: F_gt is fitted to them, the metrics computed on them). The pair is changed and returned."""
    from fviz.data.sources import WithCorrespondences, attach

    if not isinstance(pair, Pair):
        raise FvizError(f"pair: expected an fviz.Pair, got {type(pair).__name__}")
    if matches is None and gt_matches is None:
        raise FvizError("matches: give a matches file, gt_matches, or both")
    given = WithCorrespondences(None, None if matches is None else _path(matches, "matches"),
                                None if gt_matches is None else _path(gt_matches, "gt_matches"), n_pairs=1)
    return attach(pair, given.matches, given.gt_matches)
