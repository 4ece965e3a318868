"""A pair of your own arrays (or image files) with whatever you know of their geometry: :func:`pair_from_images`
(public as ``fviz.pair_from_images``), and the checks of its arguments (one-line FvizError naming the argument)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from fviz.data.pair import Pair, PairId
from fviz.errors import FvizError


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


def checked_matrix(value: Any, what: str, shapes: tuple[tuple[int, ...], ...] = ((3, 3),)) -> np.ndarray | None:
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
        m = checked_matrix(value, "K" if K is not None else what, ((3, 3), (4,)))
        Ks[what] = None if m is None else intrinsics(m.ravel(), "K" if K is not None else what)
    if (Ks["K_a"] is None) != (Ks["K_b"] is None):
        raise FvizError(f"{'K_b' if Ks['K_b'] is None else 'K_a'}: missing (give both K_a and K_b, or one K)")
    if (R is None) != (t is None):
        raise FvizError(f"{'t' if t is None else 'R'}: missing (a pose needs both R and t)")
    T_ab = None
    if R is not None:
        from fviz.data.images import pose_matrix

        T_ab = np.eye(4)
        T_ab[:3, :3], T_ab[:3, 3] = checked_matrix(R, "R"), checked_matrix(t, "t", ((3,), (3, 1))).ravel()
        T_ab = pose_matrix(T_ab.ravel(), "R")
    F = checked_matrix(F_gt, "F_gt")
    if F is not None:
        if not is_valid(F):
            raise FvizError("F_gt: all zero")
        F = normalize(check_rank2(F / np.abs(F).max(), "F_gt"), "fbn")
    pid = PairId("images", name, "pair", 0, 1, root=str(Path(path_a).parent) if path_a else "",
                 image_a=Path(path_a).name if path_a else "a", image_b=Path(path_b).name if path_b else "b")
    extra = {"path_a": path_a, "path_b": path_b} if path_a and path_b else {}
    return pair_of_arrays(pid, img_a, img_b, Ks["K_a"], Ks["K_b"], T_ab, F, what="R/t/F_gt", extra=extra, notes=notes,
                          shared_K="K" if K is not None else None)
