"""Options shared by the commands that select pairs and run estimators (inspect, eval, triage)."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Annotated, Callable, Optional

import typer

from fviz.errors import FvizError

KITTI_ROOT_ENV = "FVIZ_KITTI_ROOT"


def checked(flag: str, ok: Callable[[float], bool], rule: str) -> Callable:
    """A typer callback: the value, or a one-line FvizError ``FLAG VALUE: RULE`` (exit 2) before any work."""

    def callback(value):
        if value is not None and not ok(value):
            raise FvizError(f"{flag} {value}: {rule}")
        return value

    return callback


def positive(flag: str) -> Callable:
    return checked(flag, lambda v: math.isfinite(v) and v > 0, "must be a number > 0")


def fraction(flag: str) -> Callable:
    return checked(flag, lambda v: math.isfinite(v) and 0 < v <= 1, "must be a number in (0, 1]")


def check_threshold(value: str | None) -> str | None:
    """``--threshold``: a number > 0, ``sweep`` or a comma list of numbers, else a one-line error before any work."""
    from fviz import api

    if value is None or value.strip() == "sweep" or "," in value:
        return value if value is None else (api.pairs.threshold_specs((), value) and value)
    try:
        number = float(value)
    except ValueError:
        raise FvizError(f"--threshold {value!r}: expected a number > 0 (px), a comma list of them, or sweep") from None
    positive("--threshold")(number)
    return value


def check_recording_path(path: Path | None) -> Path | None:
    """``--out`` names a recording: it must end in .rrd (existing special files are the writer's business)."""
    if path is not None and path.suffix != ".rrd" and not (path.exists() and not path.is_file()):
        raise FvizError(f"--out {path}: a recording must end in .rrd (e.g. {path.with_suffix('.rrd')})")
    return path


def check_out_dir(path: Path, flag: str = "--out-dir") -> None:
    """A one-line error when ``path`` (or, before it exists, its nearest existing parent) is not a folder
    fviz can write to; nothing is created here (:func:`fviz.api.runs.writable_folder`)."""
    from fviz import api

    api.runs.writable_folder(path, flag)

KittiRoot = Annotated[Optional[Path], typer.Option("--kitti-root", help=f"KITTI folder (odometry or raw layout); default ${KITTI_ROOT_ENV}.")]
Sequence_ = Annotated[Optional[str], typer.Option("--sequence", help="Odometry sequence, e.g. 00.")]
Drive = Annotated[Optional[str], typer.Option("--drive", help="Raw drive, e.g. 2011_09_26_drive_0001.")]
PairKind = Annotated[str, typer.Option("--pair", help="stereo (two cameras, one frame) or temporal (frame t -> t+step).")]
Step = Annotated[int, typer.Option("--step", help="Frame step of temporal pairs.")]
Cams = Annotated[Optional[str], typer.Option("--cams", help="Cameras a,b (default 0,1 for stereo, 0,0 for temporal; 2,3 and 2,2 where only the colour images exist). A gray/colour pair (0,2) is evaluated in gray, with a note.")]
Estimators = Annotated[Optional[list[str]], typer.Option("--estimator", "-e", help="Repeatable: 7point, 8point, lmeds, ransac, magsac, usac-default, usac-accurate, usac-prosac, usac-fm8pts, usac-parallel, poselib, poselib-E, colmap, deep (the bundled networks: not better than ahead or mean:SEQ on held-out pose AUC, see docs/training.md), deep:motion, deep:stereo, deep:PATH, module:function, ahead; in eval/triage also mean:SEQ,... and oracle-mean.")]
Features = Annotated[str, typer.Option("--features", help="sift, orb or akaze; with the learned extra (pip install 'fviz[learned]'): xfeat, xfeat+lighterglue, disk+lightglue.")]


def _keypoints(value: int) -> int:
    from fviz import api  # lazily: numpy stays out of --help

    top = api.pairs.MAX_KEYPOINTS
    return checked("--max-keypoints", lambda n: 1 <= n <= top, f"must be 1 .. {top}")(value)


MaxKeypoints = Annotated[int, typer.Option("--max-keypoints", help="Keypoints per image (1 .. 1000000).", callback=_keypoints)]
Ratio = Annotated[float, typer.Option("--ratio", help="Lowe ratio test.", callback=fraction("--ratio"))]
Mutual = Annotated[bool, typer.Option("--mutual/--no-mutual", help="Keep only mutual nearest neighbours.")]
Threshold = Annotated[str, typer.Option("--threshold", metavar="PX|LIST|sweep", help="Inlier threshold of robust estimators (px); 'sweep' (0.25,0.5,1,2,4) or a list 0.5,1,2 runs each robust estimator at every value plus its per-pair oracle (NAME@T, NAME@oracle).", callback=check_threshold)]



def thresholds(names: tuple[str, ...], threshold: str) -> tuple[tuple[str, ...], float]:
    """(estimator specs, scalar threshold) of ``--estimator`` and ``--threshold`` (a sweep expands the specs)."""
    from fviz import api

    return api.pairs.threshold_specs(names, str(threshold))
Confidence = Annotated[float, typer.Option("--confidence", help="Confidence of robust estimators.", callback=fraction("--confidence"))]
MaxIters = Annotated[int, typer.Option("--max-iters", help="Iteration cap of robust estimators.",
                                       callback=checked("--max-iters", lambda n: 1 <= n < 2**31, "must be 1 .. 2147483647"))]
Seed = Annotated[int, typer.Option("--seed", help="Random seed (magsac, poselib, colmap: OpenCV fixes the others'; synthetic scene).")]
EstimatorTimeout = Annotated[float, typer.Option("--estimator-timeout", help="Seconds one estimator may take on one pair; past it, it fails that pair (and the run goes on).",
                                                callback=positive("--estimator-timeout"))]
Norm = Annotated[str, typer.Option("--norm", help="Normalization for EPI-ABS / EPI-SQR: fbn, abs or etr.")]
EvalThreshold = Annotated[float, typer.Option("--eval-threshold", help="Evaluation matches: GT symmetric epipolar distance below this (px).", callback=positive("--eval-threshold"))]
Synthetic = Annotated[bool, typer.Option("--synthetic", help="A synthetic KITTI-like scene instead of KITTI (no download).")]


def parse_cams(cams: str | None) -> tuple[int, int] | None:
    if cams is None:
        return None
    parts = cams.replace(" ", "").split(",")
    try:
        a, b = (int(p) for p in parts)
    except ValueError:
        raise FvizError(f"--cams {cams!r}: expected two camera numbers, e.g. 0,1") from None
    return a, b


def kitti_root(root: Path | None) -> Path:
    if root is not None:
        return root
    if os.environ.get(KITTI_ROOT_ENV):
        return Path(os.environ[KITTI_ROOT_ENV])
    raise FvizError(f"--kitti-root: missing (or set ${KITTI_ROOT_ENV}); use --synthetic for a scene that needs no dataset")

# ------------------------------------------------------------------ a user's data (fviz.data.images, pairsfile, colmap)
ImageA = Annotated[Optional[Path], typer.Option("--image-a", help="Your image a (any OpenCV-readable file; EXIF orientation applied).")]
ImageB = Annotated[Optional[Path], typer.Option("--image-b", help="Your image b.")]
KBoth = Annotated[Optional[str], typer.Option("--K", help="Intrinsics of both images: fx,fy,cx,cy or 9 numbers (OpenCV pixel origin).")]
KA = Annotated[Optional[str], typer.Option("--K-a", help="Intrinsics of image a: fx,fy,cx,cy or 9 numbers.")]
KB = Annotated[Optional[str], typer.Option("--K-b", help="Intrinsics of image b.")]
TAB = Annotated[Optional[str], typer.Option("--T-ab", help="Ground-truth relative pose, 12 or 16 row-major numbers (or a file): x_b = R x_a + t.")]
FGT = Annotated[Optional[str], typer.Option("--F-gt", help="Ground-truth F (x_b^T F x_a = 0): a file or 9 row-major numbers.")]
PairsFile = Annotated[Optional[Path], typer.Option("--pairs", help="Pairs file (SuperGlue/LightGlue layout: name0 name1 [rot0 rot1 K0 K1 T_0to1]); with --colmap: the pairs to take.")]
ImagesDir = Annotated[Optional[Path], typer.Option("--images", help="Folder the names of --pairs / --colmap are relative to.")]
Colmap = Annotated[Optional[Path], typer.Option("--colmap", help="COLMAP model folder (cameras, images, points3D; .txt or .bin), read with pycolmap.")]
MinShared = Annotated[int, typer.Option("--min-shared", help="With --colmap: pairs of images sharing at least this many 3D points.",
                                        callback=checked("--min-shared", lambda n: n >= 1, "must be >= 1"))]
MatchesFile = Annotated[Optional[Path], typer.Option("--matches", help="Your matches instead of fviz's features: hloc matches.h5 (features.h5 beside it), SuperGlue *_matches.npz (or a folder of them), or x_a y_a x_b y_b [score] text/npz.")]
GtMatches = Annotated[Optional[Path], typer.Option("--gt-matches", help="Ground-truth correspondences (x_a y_a x_b y_b, or AdelaideRMF x1 y1 1 x2 y2 1 label): F_gt is fitted to them and the metrics computed on them.")]
