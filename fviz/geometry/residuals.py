"""Per-correspondence residuals of F (convention ``x_b^T F x_a = 0``, pixels).

All take F (3, 3) and matched points x_a, x_b (N, 2) and return (N,).
"""

from __future__ import annotations

import numpy as np

from fviz.geometry.epipolar import homogeneous


def _terms(F: np.ndarray, x_a: np.ndarray, x_b: np.ndarray):
    F = np.asarray(F, dtype=np.float64)
    xa, xb = homogeneous(x_a), homogeneous(x_b)
    Fxa = xa @ F.T  # (N, 3) lines in b
    Ftxb = xb @ F  # (N, 3) lines in a
    r = np.einsum("ni,ni->n", xb, Fxa)  # x_b^T F x_a
    return r, Fxa, Ftxb


def algebraic(F: np.ndarray, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """|x_b^T F x_a| (depends on the scale of F: normalize F first)."""
    return np.abs(_terms(F, x_a, x_b)[0])


def symmetric_epipolar_distance(F: np.ndarray, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """Mean of the two point-to-epipolar-line distances, in pixels:

    ( d(x_b, F x_a) + d(x_a, F^T x_b) ) / 2.
    """
    r, Fxa, Ftxb = _terms(F, x_a, x_b)
    r = np.abs(r)
    with np.errstate(divide="ignore", invalid="ignore"):
        d_b = r / np.linalg.norm(Fxa[:, :2], axis=1)
        d_a = r / np.linalg.norm(Ftxb[:, :2], axis=1)
    return 0.5 * (d_a + d_b)


def squared_epipolar_distances(F: np.ndarray, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """Sum of the squared point-to-epipolar-line distances, in px^2 (Hartley & Zisserman's symmetric epipolar
    distance, eq. 11.10): d(x_b, F x_a)^2 + d(x_a, F^T x_b)^2. The paper's evaluation filter keeps the matches where
    it is below 2 under the ground truth ("within about one pixel"); fviz's :func:`symmetric_epipolar_distance` is
    the *mean* of the two distances, in px (below 2 px: up to 4 px from each line)."""
    r, Fxa, Ftxb = _terms(F, x_a, x_b)
    with np.errstate(divide="ignore", invalid="ignore"):
        return r**2 / (Fxa[:, 0] ** 2 + Fxa[:, 1] ** 2) + r**2 / (Ftxb[:, 0] ** 2 + Ftxb[:, 1] ** 2)


def sampson_distance(F: np.ndarray, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """First-order geometric error in pixels (the square root of OpenCV's ``sampsonDistance``)."""
    r, Fxa, Ftxb = _terms(F, x_a, x_b)
    den = Fxa[:, 0] ** 2 + Fxa[:, 1] ** 2 + Ftxb[:, 0] ** 2 + Ftxb[:, 1] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(r) / np.sqrt(den)


def epipolar_residuals(F: np.ndarray, x_a: np.ndarray, x_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(:func:`algebraic`, :func:`symmetric_epipolar_distance`, :func:`sampson_distance`) of F at once, from
    one evaluation of the lines.  (3, 3), (N, 2), (N, 2) -> 3 x (N,)."""
    r, Fxa, Ftxb = _terms(F, x_a, x_b)
    r = np.abs(r)
    nb, na = Fxa[:, 0] ** 2 + Fxa[:, 1] ** 2, Ftxb[:, 0] ** 2 + Ftxb[:, 1] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        return r, 0.5 * (r / np.sqrt(na) + r / np.sqrt(nb)), r / np.sqrt(na + nb)
