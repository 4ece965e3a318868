"""Fundamental matrices: construction, normalization, rank 2, comparison.

Convention (the one used everywhere in fviz): F maps image ``a`` to image ``b``,

    x_b^T F x_a = 0,

with x in homogeneous *pixel* coordinates, OpenCV's origin (pixel centres at integers,
(0, 0) is the centre of the top-left pixel). OpenCV's ``findFundamentalMat(points1, points2)``
follows the same convention with points1 = x_a, points2 = x_b.

All functions accept a single matrix (3, 3) or a batch (..., 3, 3).
"""

from __future__ import annotations

import numpy as np

from fviz.errors import FvizError

NORMS = ("etr", "fbn", "abs")
ETR_EPS = 1e-9  # |F33| / ||F|| below this: ETR normalization is undefined


class NormalizationError(FvizError):
    """A normalization that is undefined for the given F (ETR with F33 ~ 0)."""


def skew(t: np.ndarray) -> np.ndarray:
    """Cross-product matrix: skew(t) @ v == cross(t, v).  (..., 3) -> (..., 3, 3)."""
    t = np.asarray(t, dtype=np.float64)
    z = np.zeros(t.shape[:-1])
    return np.stack(
        [
            np.stack([z, -t[..., 2], t[..., 1]], -1),
            np.stack([t[..., 2], z, -t[..., 0]], -1),
            np.stack([-t[..., 1], t[..., 0], z], -1),
        ],
        -2,
    )


def fundamental_from_projections(P_a: np.ndarray, P_b: np.ndarray) -> np.ndarray:
    """F from two 3x4 projection matrices of one world frame (Hartley & Zisserman 9.2.2).

    F = [e_b]x P_b P_a^+, with e_b = P_b C_a and C_a the centre of camera a.
    (..., 3, 4), (..., 3, 4) -> (..., 3, 3), scaled to unit Frobenius norm.
    """
    P_a = np.asarray(P_a, dtype=np.float64)
    P_b = np.asarray(P_b, dtype=np.float64)
    C_a = np.linalg.svd(P_a)[2][..., -1, :]  # right null vector of P_a
    e_b = np.einsum("...ij,...j->...i", P_b, C_a)
    F = skew(e_b) @ P_b @ np.linalg.pinv(P_a)
    return normalize(F, "fbn")


def fundamental_from_motion(K_a: np.ndarray, K_b: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """F = K_b^-T [t]x R K_a^-1 for the motion X_b = R X_a + t (the paper's reconstruction layer).

    (..., 3, 3), (..., 3, 3), (..., 3, 3), (..., 3) -> (..., 3, 3), not normalized.
    """
    K_b_inv_T = np.swapaxes(np.linalg.inv(K_b), -1, -2)
    return K_b_inv_T @ skew(t) @ R @ np.linalg.inv(K_a)


def transfer_fundamental(F: np.ndarray, H_a: np.ndarray, H_b: np.ndarray) -> np.ndarray:
    """The same epipolar geometry in new pixel coordinates x_a' = H_a x_a, x_b' = H_b x_b: H_b^-T F H_a^-1.

    (..., 3, 3) x 3 -> (..., 3, 3), not normalized (e.g. rectified KITTI -> the unrectified cameras, whose F
    has F33 != 0: :func:`fviz.data.kitti.raw_cameras`).
    """
    H_b_inv_T = np.swapaxes(np.linalg.inv(np.asarray(H_b, np.float64)), -1, -2)
    return H_b_inv_T @ np.asarray(F, np.float64) @ np.linalg.inv(np.asarray(H_a, np.float64))


def normalize(F: np.ndarray, norm: str) -> np.ndarray:
    """The paper's normalization layers (Sec. 3.2). (..., 3, 3) -> (..., 3, 3).

    - ``etr``: divide by F[2, 2] (undefined when F33 ~ 0, e.g. rectified stereo: raises);
    - ``fbn``: divide by the Frobenius norm, sign fixed so the largest-|.| entry is positive;
    - ``abs``: divide by the largest absolute entry (signed: that entry becomes +1).
    Entries tied in |.| (within 1e-9, relative): the first one, in row-major order, whatever the scale of F.
    """
    F = np.asarray(F, dtype=np.float64)
    norm = norm.lower()
    flat = F.reshape(*F.shape[:-2], 9)
    fro = np.linalg.norm(flat, axis=-1)
    if norm == "etr":
        f33 = F[..., 2, 2]
        if np.any(np.abs(f33) <= ETR_EPS * np.maximum(fro, 1e-300)):
            raise NormalizationError(
                "ETR normalization is undefined: |F33| ~ 0 (rectified stereo pairs have F33 = 0); use --norm fbn or abs"
            )
        return F / f33[..., None, None]
    # the pivot: the first entry within a relative 1e-9 of the largest |.| (ties stay ties under scaling)
    mag = np.abs(flat)
    first = (mag >= (1.0 - 1e-9) * mag.max(-1, keepdims=True)).argmax(-1)
    pivot = np.take_along_axis(flat, first[..., None], -1)[..., 0]
    if norm == "fbn":
        return F * (np.sign(pivot) / fro)[..., None, None]
    if norm == "abs":
        return F / pivot[..., None, None]
    raise FvizError(f"unknown norm {norm!r}: choose one of {', '.join(NORMS)}")


def enforce_rank2(F: np.ndarray) -> np.ndarray:
    """Closest rank-2 matrix in Frobenius norm (zero the smallest singular value)."""
    U, S, Vt = np.linalg.svd(np.asarray(F, dtype=np.float64))
    S = S.copy()
    S[..., 2] = 0.0
    return U @ (S[..., :, None] * Vt)


def f_distance(F_est: np.ndarray, F_ref: np.ndarray) -> np.ndarray:
    """Distance of two F up to scale and sign: min ||F1 -+ F2||_F of unit-norm F, in [0, sqrt(2)]."""
    A = normalize(F_est, "fbn").reshape(*np.shape(F_est)[:-2], 9)
    B = normalize(F_ref, "fbn").reshape(*np.shape(F_ref)[:-2], 9)
    return np.minimum(np.linalg.norm(A - B, axis=-1), np.linalg.norm(A + B, axis=-1))


def is_valid(F: np.ndarray | None) -> bool:
    """A usable 3x3 F: finite and not all zero."""
    if F is None:
        return False
    F = np.asarray(F)
    return F.shape == (3, 3) and bool(np.all(np.isfinite(F))) and bool(np.abs(F).max() > 0)
