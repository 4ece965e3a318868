"""Correspondences a user brings: their matches (``--matches``, used instead of fviz's features) and
ground-truth correspondences (``--gt-matches``, F_gt fitted to them). Pixel coordinates come out in
fviz's convention (OpenCV: origin at the centre of the top-left pixel).

``--matches`` formats:

- hloc: a matches file with its features file beside it: ``FEATURES.h5`` for hloc's
  ``FEATURES_MATCHER_PAIRS.h5`` (hloc's names), else ``features.h5``, else the one other .h5 in that folder
  holding keypoints: per image ``features[name]["keypoints"]`` (N, 2); per pair ``matches[pair]["matches0"]``
  (N0,) integer indices, -1 = unmatched, and ``matching_scores0`` (N0,); ``pair`` is hloc's
  ``names_to_pair`` (names with "/" as "-", joined by "/", or the older "_"), either order. hloc keeps
  keypoints with OpenCV's origin and adds 0.5 itself when it hands them to COLMAP (hloc/triangulation.py
  ``import_features``): no shift here (:data:`HLOC_PIXEL_SHIFT`). hloc reads an image as stored (no EXIF
  orientation; ``image_size`` is the stored width, height) and knows no pairs file's rot; fviz shows the
  image with both applied, so hloc's keypoints are turned with them (a note says so). fviz's own files
  (a run's features.h5) hold keypoints of the shown image.
- SuperGlue ``*_matches.npz`` (``keypoints0``, ``keypoints1``, ``matches`` (N0,) -1 = unmatched,
  ``match_confidence``), one file, or a folder of ``{stem0}_{stem1}_matches.npz`` (match_pairs.py's names).
  Keypoints must be at the images' resolution (match_pairs.py resizes to 640x480 unless ``--resize -1``).
- plain: text rows ``x_a y_a x_b y_b [score]`` (``#`` comments), or an npz with ``x_a``, ``x_b`` (M, 2) and
  optional ``scores`` (M,), or ``matches`` (M, 4 or 5).

``--gt-matches``: text rows ``x_a y_a x_b y_b``, or AdelaideRMF / kusvod2 ``x1 y1 1 x2 y2 1 label`` (label 0
= outlier, left out); one file, or a folder of ``{stem0}_{stem1}.txt`` (either order), or kusvod2's ``{name}_pts.txt``
for images ``{name}A``, ``{name}B``. Coordinates are taken in OpenCV's
convention (subtract 1 from MATLAB's 1-based pixels first). The authors' model F beside them (``X_model.txt`` for
``X_pts.txt`` or ``X.txt``) is F_gt, in whichever convention the labels fit (:func:`read_model_f`); without one
(or with one of nine zeros, kusvod2's placeholder; a note says so), F_gt is fitted on the labels' Sampson distance
(:func:`refined_fit`).

A bad file is one line naming the file and the line (or the HDF5 dataset).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fviz.errors import FvizError

HLOC_PIXEL_SHIFT = 0.0  # hloc's keypoints already have OpenCV's origin (see the module doc)
MIN_GT = 8  # correspondences needed to fit F_gt (8 for the 8-point it starts from)
DEGENERATE_PLANE_FRACTION = 0.9  # of the labelled points on one homography: F_gt not determined by them


@dataclass
class Correspondences:
    """x_a, x_b: (M, 2) float64 pixels (OpenCV origin); scores: (M,) or None; n_keypoints: (Na, Nb) the
    keypoints the matches were drawn from, when the file says; path: where they come from."""

    x_a: np.ndarray
    x_b: np.ndarray
    scores: np.ndarray | None = None
    n_keypoints: tuple[int, int] | None = None
    path: str = ""

    def swapped(self) -> "Correspondences":
        n = None if self.n_keypoints is None else self.n_keypoints[::-1]
        return Correspondences(self.x_b, self.x_a, self.scores, n, self.path)


# ------------------------------------------------------------------------------ text / npz tables


def read_table(path: Path, columns: tuple[int, ...], what: str) -> tuple[np.ndarray, list[int]]:
    """Rows of numbers (``#`` comments, blank lines skipped) with one of ``columns`` counts -> (rows (M, C),
    their line numbers); one-line errors name the file and line."""
    from fviz.data.images import read_text

    text = read_text(path, what)
    rows, lines, width = [], [], None
    for n, raw in enumerate(text.splitlines(), 1):
        fields = raw.split("#", 1)[0].replace(",", " ").split()
        if not fields:
            continue
        try:
            values = [float(v) for v in fields]
        except ValueError:
            raise FvizError(f"{path}:{n}: not numbers ({raw.strip()[:60]!r})") from None
        if len(values) not in columns or (width is not None and len(values) != width):
            expected = width if width is not None else " or ".join(map(str, columns))
            raise FvizError(f"{path}:{n}: {len(values)} columns, expected {expected}")
        if not np.isfinite(values).all():
            raise FvizError(f"{path}:{n}: NaN or infinite numbers")
        width = len(values)
        rows.append(values)
        lines.append(n)
    if not rows:
        raise FvizError(f"{what} {path}: no correspondences in it")
    return np.array(rows, float), lines


def check_inside(c: Correspondences, pair, lines: list[int] | None = None) -> Correspondences:
    """A point outside its image is a one-line error (a wrong file, or keypoints of a resized image)."""
    for x, (w, h), v in ((c.x_a, pair.size_a, "a"), (c.x_b, pair.size_b, "b")):
        bad = np.flatnonzero((x[:, 0] < -0.5) | (x[:, 1] < -0.5) | (x[:, 0] > w - 0.5) | (x[:, 1] > h - 0.5))
        if len(bad):
            i = int(bad[0])
            where = f"{c.path}:{lines[i]}" if lines else f"{c.path}: correspondence {i}"
            raise FvizError(f"{where}: point ({x[i, 0]:.1f}, {x[i, 1]:.1f}) lies outside the {w}x{h} image {v}")
    return c


def small_extent_note(c: Correspondences, pair) -> str | None:
    """A note when every keypoint sits in a corner box of half the image (keypoints of a resized image?)."""
    (wa, ha), (wb, hb) = pair.size_a, pair.size_b
    if len(c.x_a) >= 20 and c.x_a[:, 0].max() < wa / 2 and c.x_a[:, 1].max() < ha / 2 and c.x_b[:, 0].max() < wb / 2 \
            and c.x_b[:, 1].max() < hb / 2:
        return (f"the matches of {c.path} all lie in the top-left quarter of the images: were they computed on "
                "resized images? (SuperGlue's match_pairs.py resizes to 640x480 unless --resize -1)")
    return None


def _pair_file(folder: Path, pair, pattern: str, what: str) -> Path:
    """The per-pair file of a folder: ``pattern`` formatted with the images' stems (either order); for text files
    also kusvod2's ``{name}_pts.txt`` (and ``{name}.txt``) where the stems are ``{name}`` plus a suffix (A/B, 1/2)."""
    stems = [Path(n).stem for n in image_names(pair)]
    names = [pattern.format(stem0=stems[0], stem1=stems[1]), pattern.format(stem0=stems[1], stem1=stems[0])]
    common = os.path.commonprefix(stems).rstrip("_-. ")
    if pattern.endswith(".txt") and common and common not in stems:
        names += [f"{common}_pts.txt", f"{common}.txt"]
    for name in dict.fromkeys(names):
        if (folder / name).is_file():
            return folder / name
    others = [n for n in dict.fromkeys(names) if n != names[0]]
    nor = f" (nor {', '.join(others)})" if others else ""
    raise FvizError(f"{what} {folder}: no {names[0]} for the pair {pair.id.name}{nor}")


def image_names(pair) -> tuple[str, str]:
    return (pair.id.image_a or Path(pair.extra.get("path_a", "a")).name,
            pair.id.image_b or Path(pair.extra.get("path_b", "b")).name)


class TableReader:
    """Plain-text or npz correspondences: one file (one pair) or a folder of per-pair files."""

    def __init__(self, path: Path, what: str, columns: tuple[int, ...], pattern: str, gt: bool):
        self.path, self.what, self.columns, self.pattern, self.gt = path, what, columns, pattern, gt
        self.single = not path.is_dir()

    def for_pair(self, pair) -> Correspondences:
        path = self.path if self.single else _pair_file(self.path, pair, self.pattern, self.what)
        if path.suffix == ".npz":
            c, lines = _plain_npz(path, self.what), None
        else:
            rows, lines = read_table(path, self.columns, self.what)
            if rows.shape[1] == 7:  # AdelaideRMF: x1 y1 1 x2 y2 1 label
                keep = rows[:, 6] != 0
                lines = [n for n, k in zip(lines, keep) if k]
                rows = rows[keep][:, [0, 1, 3, 4]]
            c = Correspondences(rows[:, 0:2].copy(), rows[:, 2:4].copy(), rows[:, 4].copy() if rows.shape[1] == 5 else None,
                                path=str(path))
        return check_inside(c, pair, lines)


def _plain_npz(path: Path, what: str) -> Correspondences:
    with open_npz(path, what) as npz:
        z = _npz_arrays(npz, path, what, tuple(npz.files))
        if "x_a" in z and "x_b" in z:
            x_a, x_b = np.asarray(z["x_a"], float), np.asarray(z["x_b"], float)
            scores = np.asarray(z["scores"], float) if "scores" in z else None
        elif "matches" in z and np.ndim(z["matches"]) == 2 and np.shape(z["matches"])[1] in (4, 5):
            m = np.asarray(z["matches"], float)
            x_a, x_b, scores = m[:, 0:2], m[:, 2:4], m[:, 4] if m.shape[1] == 5 else None
        else:
            raise FvizError(f"{what} {path}: expected arrays x_a, x_b (M, 2) [scores], or matches (M, 4|5), "
                            f"or SuperGlue's keypoints0/keypoints1/matches; found {', '.join(z) or 'none'}")
    if x_a.shape != x_b.shape or x_a.ndim != 2 or x_a.shape[1] != 2:
        raise FvizError(f"{what} {path}: x_a {x_a.shape} and x_b {x_b.shape} must both be (M, 2)")
    if scores is not None and scores.shape != (len(x_a),):
        raise FvizError(f"{what} {path}: scores {scores.shape}, expected ({len(x_a)},)")
    if not (np.isfinite(x_a).all() and np.isfinite(x_b).all()):
        raise FvizError(f"{what} {path}: NaN or infinite coordinates")
    return Correspondences(x_a, x_b, scores, path=str(path))


def open_npz(path: Path, what: str):
    import zipfile

    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise FvizError(f"{what} {path}: not a readable npz ({' '.join(str(exc).split()) or type(exc).__name__})") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise FvizError(f"{what} {path}: a single .npy array, not an npz of named arrays")
    return z


def _npz_arrays(z, path: Path, what: str, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The arrays ``keys`` (those present) of an open npz; a cut or corrupt member is a one-line error."""
    import zipfile

    out = {}
    for k in keys:
        if k in z:
            try:
                out[k] = z[k]
            except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
                raise FvizError(f"{what} {path}: array '{k}' cannot be read (a cut or corrupt file? "
                                f"{' '.join(str(exc).split())[:80] or type(exc).__name__})") from None
    return out


# ------------------------------------------------------------------------------ SuperGlue npz


def from_match_vector(kp0: np.ndarray, kp1: np.ndarray, matches0: np.ndarray, scores0: np.ndarray | None,
                      where: str) -> Correspondences:
    """Keypoints (N0, 2), (N1, 2) and matches0 (N0,) (index into kp1, -1 = unmatched) -> correspondences."""
    kp0, kp1 = np.asarray(kp0, float), np.asarray(kp1, float)
    raw = np.asarray(matches0).reshape(-1)
    for name, kp in (("keypoints0", kp0), ("keypoints1", kp1)):
        if kp.ndim != 2 or kp.shape[1] != 2:
            raise FvizError(f"{where}: {name} has shape {kp.shape}, expected (N, 2)")
    if not (np.issubdtype(raw.dtype, np.integer) or np.issubdtype(raw.dtype, np.floating)):
        raise FvizError(f"{where}: matches of type {raw.dtype}, expected integer indices")
    if np.issubdtype(raw.dtype, np.floating):
        bad = np.flatnonzero(~np.isfinite(raw) | (raw != np.round(raw)))
        if len(bad):
            raise FvizError(f"{where}: match {int(bad[0])} is {float(raw[bad[0]])}, not a keypoint index (integers, -1 = unmatched)")
    m = raw.astype(np.int64)
    if len(m) != len(kp0):
        raise FvizError(f"{where}: {len(m)} matches for {len(kp0)} keypoints of image a")
    if m.min(initial=-1) < -1:
        i = int(np.argmin(m))
        raise FvizError(f"{where}: match {i} is {int(m[i])}: an index must be -1 (unmatched) or a keypoint of image b")
    if m.max(initial=-1) >= len(kp1):
        raise FvizError(f"{where}: a match indexes keypoint {int(m.max())} of image b, which has {len(kp1)}")
    valid = np.flatnonzero(m >= 0)
    for name, kp, idx in (("keypoints0", kp0, valid), ("keypoints1", kp1, m[valid])):
        bad = idx[~np.isfinite(kp[idx]).all(1)]
        if len(bad):
            raise FvizError(f"{where}: {name}[{int(bad[0])}] is ({kp[bad[0], 0]}, {kp[bad[0], 1]}): a matched keypoint "
                            "must be finite")
    scores = None
    if scores0 is not None:
        scores0 = np.asarray(scores0, float).reshape(-1)
        if len(scores0) != len(m):
            raise FvizError(f"{where}: {len(scores0)} match scores for {len(m)} matches (one per keypoint of image a)")
        scores = scores0[valid]
    return Correspondences(kp0[valid], kp1[m[valid]], scores, (len(kp0), len(kp1)), where)


class SuperGlueReader:
    """SuperGlue's match_pairs.py output: one ``*_matches.npz`` or a folder of them."""

    KEYS = ("keypoints0", "keypoints1", "matches")

    def __init__(self, path: Path):
        self.path = path
        self.single = not path.is_dir()

    def for_pair(self, pair) -> Correspondences:
        path = self.path if self.single else _pair_file(self.path, pair, "{stem0}_{stem1}_matches.npz", "--matches")
        with open_npz(path, "--matches") as z:
            missing = [k for k in self.KEYS if k not in z]
            if missing:
                raise FvizError(f"--matches {path}: no '{missing[0]}' array (SuperGlue's keypoints0, keypoints1, matches)")
            arrays = _npz_arrays(z, path, "--matches", (*self.KEYS, "match_confidence"))
            c = from_match_vector(arrays["keypoints0"], arrays["keypoints1"], arrays["matches"],
                                  arrays.get("match_confidence"), str(path))
        stems = [Path(n).stem for n in image_names(pair)]
        if not self.single and path.name.startswith(f"{stems[1]}_{stems[0]}_") and stems[0] != stems[1]:
            c = c.swapped()
        return check_inside(c, pair)


# ------------------------------------------------------------------------------ hloc h5


def model_file(c: Correspondences) -> Path | None:
    """The authors' model F beside a ground-truth correspondence file (kusvod2 / AdelaideRMF: ``X_pts.txt`` or
    ``X.txt`` -> ``X_model.txt``), None when there is none."""
    path = Path(c.path)
    stem = path.stem.removesuffix("_pts").removesuffix("_vpts")
    candidate = path.with_name(f"{stem}_model.txt")
    return candidate if candidate.is_file() else None


def read_model_f(path: Path, c: Correspondences) -> tuple[np.ndarray, bool] | None:
    """(F, transposed): the 9 numbers of a model file as the F of ``x_b^T F x_a = 0``. Such files do not all share
    fviz's convention (some hold F with ``x_a^T F x_b = 0``): the one of F and F^T that the labelled points fit
    better (median SED) is taken, and ``transposed`` says which. None for a file of nine zeros (the published
    kusvod2 files ship such placeholders for pairs without a model)."""
    from fviz.geometry import is_valid, normalize, symmetric_epipolar_distance

    rows, _ = read_table(path, (3, 9), "--gt-matches model F")
    if rows.size != 9:
        raise FvizError(f"--gt-matches model F {path}: {rows.size} numbers, expected the 9 of a 3x3 F")
    F = rows.reshape(3, 3)
    if not np.abs(F).max() > 0:
        return None
    if not is_valid(F):
        raise FvizError(f"--gt-matches model F {path}: not finite")
    F = normalize(F / np.abs(F).max(), "fbn")
    direct, transposed = (float(np.median(symmetric_epipolar_distance(G, c.x_a, c.x_b))) for G in (F, F.T))
    return (F.T, True) if transposed < direct else (F, False)


REFINE_LOSS_PX = 2.0  # the Cauchy loss's scale of refined_fit: hand-labelling is good to a few pixels


def refined_fit(x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray | None:
    """F of correspondences (N, 2) fitted on their Sampson distance, robustly, not on the 8-point's algebraic
    error: OpenCV's normalized 8-point, then PoseLib's non-linear refinement under a Cauchy loss of scale
    REFINE_LOSS_PX (a mislabelled point pulls little). Deterministic (no sampling). (3, 3) unit norm, or None."""
    import cv2
    import poselib

    from fviz.geometry import normalize

    F, _ = cv2.findFundamentalMat(x_a.astype(np.float64), x_b.astype(np.float64), cv2.FM_8POINT)
    if F is None or F.shape != (3, 3):
        return None
    F, _ = poselib.refine_fundamental(x_a.astype(np.float64), x_b.astype(np.float64), F,
                                      {"loss_type": "CAUCHY", "loss_scale": REFINE_LOSS_PX})
    return normalize(F, "fbn")


def fit_gt(c: Correspondences, pair) -> tuple[np.ndarray, float, str]:
    """F_gt of ground-truth correspondences -> (F, their median SED to it (px), the note that says so): the
    authors' model F when one lies beside the file (:func:`model_file`), else a Sampson-refined fit
    (:func:`refined_fit`). Labelled points on one plane do not determine F: the note says so."""
    from fviz.geometry import symmetric_epipolar_distance
    from fviz.geometry.homography import homography_fraction

    if len(c.x_a) < MIN_GT:
        raise FvizError(f"--gt-matches {c.path}: {len(c.x_a)} correspondences, at least {MIN_GT} needed to fit F_gt")
    model = model_file(c)
    read = read_model_f(model, c) if model is not None else None
    if read is not None:
        F, transposed = read
        how = f"the authors' model F of {model}" + (" (transposed: the file's F has x_a^T F x_b = 0)" if transposed else "")
    else:
        F = refined_fit(c.x_a, c.x_b)
        if F is None:
            raise FvizError(f"--gt-matches {c.path}: no F fits these correspondences (degenerate: all on a plane or a line?)")
        how = (f"F_gt fitted to the {len(c.x_a)} ground-truth correspondences of {c.path} (8-point, then refined on "
               "their Sampson distance under a Cauchy loss)")
        if model is not None:
            how = f"{model} is all zeros (a placeholder, as kusvod2 ships for some pairs), taken as no model: {how}"
    sed = symmetric_epipolar_distance(F, c.x_a, c.x_b)
    med = float(np.median(sed))
    note = (f"{how}: their SED to it, median {med:.2g} px, max {float(sed.max()):.2g} px; the metrics are computed "
            "on them")
    if homography_fraction(c.x_a, c.x_b) >= DEGENERATE_PLANE_FRACTION:
        note += (f"; degenerate: one homography explains at least {DEGENERATE_PLANE_FRACTION:.0%} of them (a plane): "
                 "they do not determine F, so F_gt and every metric on them are unreliable")
    return F, med, note
