"""Epipolar lines, epipoles and clipping to the image (convention ``x_b^T F x_a = 0``, pixels).

Points are (N, 2) pixel arrays; lines are (N, 3) homogeneous ``(a, b, c)`` with ``a x + b y + c = 0``,
scaled so that ``a^2 + b^2 = 1`` (then ``l . x`` is a signed distance in pixels).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def homogeneous(x: np.ndarray) -> np.ndarray:
    """(..., 2) -> (..., 3) by appending 1."""
    x = np.asarray(x, dtype=np.float64)
    return np.concatenate([x, np.ones((*x.shape[:-1], 1))], axis=-1)


def apply_homography(H: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Points mapped by a homography: x' ~ H x.  (3, 3), (N, 2) -> (N, 2)."""
    y = homogeneous(x) @ np.asarray(H, dtype=np.float64).T
    return y[..., :2] / y[..., 2:]


def _unit_lines(lines: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(lines[..., :2], axis=-1, keepdims=True)
    return lines / np.where(n > 0, n, 1.0)


def lines_in_b(F: np.ndarray, x_a: np.ndarray) -> np.ndarray:
    """Epipolar lines in image b of points of image a: l_b = F x_a.  (3,3), (N,2) -> (N,3)."""
    return _unit_lines(homogeneous(x_a) @ np.asarray(F, dtype=np.float64).T)


def lines_in_a(F: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """Epipolar lines in image a of points of image b: l_a = F^T x_b.  (3,3), (N,2) -> (N,3)."""
    return _unit_lines(homogeneous(x_b) @ np.asarray(F, dtype=np.float64))


def epipoles(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Homogeneous unit epipoles (e_a, e_b) with F e_a = 0 and F^T e_b = 0.  (3,3) -> (3,), (3,).

    e_a is the image of camera b's centre in image a, e_b that of camera a in image b.
    """
    U, _, Vt = np.linalg.svd(np.asarray(F, dtype=np.float64))
    return Vt[-1], U[:, -1]


@dataclass(frozen=True)
class Epipole:
    """An epipole as the viewer needs it.

    ``point`` is the pixel position when finite (else None); ``direction`` a unit 2D vector
    pointing from the image centre towards it (for an epipole at infinity: its direction);
    ``inside`` whether it falls inside the image rectangle.
    """

    homogeneous: np.ndarray
    point: np.ndarray | None
    direction: np.ndarray
    inside: bool


INFINITY_EPS = 1e-9  # |w| / ||(x, y)|| below this: the epipole is at infinity


def describe_epipole(e: np.ndarray, width: int, height: int) -> Epipole:
    """Classify a homogeneous epipole for an image of the given size."""
    e = np.asarray(e, dtype=np.float64)
    centre = np.array([(width - 1) / 2.0, (height - 1) / 2.0])
    if abs(e[2]) <= INFINITY_EPS * np.linalg.norm(e[:2]):
        d = e[:2] / np.linalg.norm(e[:2])
        return Epipole(e, None, d, False)
    p = e[:2] / e[2]
    v = p - centre
    n = np.linalg.norm(v)
    d = v / n if n > 0 else np.array([1.0, 0.0])
    inside = bool(-0.5 <= p[0] <= width - 0.5 and -0.5 <= p[1] <= height - 0.5)
    return Epipole(e, p, d, inside)


def border_point(direction: np.ndarray, width: int, height: int) -> np.ndarray:
    """Where the ray from the image centre along ``direction`` leaves the image rectangle."""
    centre = np.array([(width - 1) / 2.0, (height - 1) / 2.0])
    half = np.array([width / 2.0, height / 2.0])
    d = np.asarray(direction, dtype=np.float64)
    with np.errstate(divide="ignore"):
        s = np.min(np.where(np.abs(d) > 0, half / np.abs(d), np.inf))
    return centre + s * d


def clip_lines(lines: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Clip homogeneous lines to the image rectangle [-0.5, W-0.5] x [-0.5, H-0.5].

    (N, 3) -> segments (N, 2, 2) and a mask (N,) of lines that cross the image
    (segments of lines that miss it are NaN).
    """
    lines = np.asarray(lines, dtype=np.float64).reshape(-1, 3)
    x0, x1, y0, y1 = -0.5, width - 0.5, -0.5, height - 0.5
    a, b, c = lines[:, 0:1], lines[:, 1:2], lines[:, 2:3]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # intersections with x = x0, x = x1 (solve for y) and y = y0, y = y1 (solve for x)
        xs = np.array([x0, x1])[None, :]
        ys_at = -(a * xs + c) / b
        ys = np.array([y0, y1])[None, :]
        xs_at = -(b * ys + c) / a
    cand = np.concatenate(
        [np.stack([np.broadcast_to(xs, ys_at.shape), ys_at], -1), np.stack([xs_at, np.broadcast_to(ys, xs_at.shape)], -1)],
        axis=1,
    )  # (N, 4, 2)
    tol = 1e-6
    ok = (
        np.isfinite(cand).all(-1)
        & (cand[..., 0] >= x0 - tol)
        & (cand[..., 0] <= x1 + tol)
        & (cand[..., 1] >= y0 - tol)
        & (cand[..., 1] <= y1 + tol)
    )
    # The two admissible points farthest apart form the segment (corners may appear twice).
    pts = np.where(ok[..., None], cand, np.nan)
    diff = pts[:, :, None, :] - pts[:, None, :, :]
    dist = np.where(np.isnan(diff).any(-1), -1.0, np.linalg.norm(np.nan_to_num(diff), axis=-1))
    flat = dist.reshape(len(lines), 16).argmax(-1)
    i, j = flat // 4, flat % 4
    rows = np.arange(len(lines))
    seg = np.stack([pts[rows, i], pts[rows, j]], axis=1)
    valid = dist.reshape(len(lines), 16).max(-1) >= 0
    seg[~valid] = np.nan
    return seg, valid
