"""Shared helpers of tests/test_sources_*.py: the fountain-P11 scene and its published cameras."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

PROJECT = Path(__file__).resolve().parents[1]
FOUNTAIN = PROJECT.parent / "shared" / "data" / "strecha" / "fountain-P11"
# Both SIFT and the deep features of a 3072x2048 photo are slow on a shared CPU: few keypoints are enough.
FAST = ("--max-keypoints", "600")
GT_METRICS = ("f_dist", "nsgd", "gt_inlier_ratio", "epipole_err_deg", "rot_err_deg", "trans_err_deg", "pose_err_deg")


def fountain() -> Path:
    if not (FOUNTAIN / "pairs_with_gt.txt").is_file():
        msg = f"fountain-P11 data missing at {FOUNTAIN}"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    return FOUNTAIN


def strecha_camera(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K, R camera->world, C) of the published NNNN.jpg.camera file (K, distortion, R, C, size)."""
    rows = [list(map(float, line.split())) for line in (fountain() / "cameras" / f"{name}.camera").read_text().splitlines() if line.strip()]
    K, R, C = np.array(rows[0:3]), np.array(rows[4:7]), np.array(rows[7])
    return K, R, C


def closed_form_F(P_a: np.ndarray, P_b: np.ndarray) -> np.ndarray:
    """Hartley & Zisserman (9.1): F = [P_b C_a]x P_b P_a^+, unit norm, sign of the largest entry positive."""
    C_a = np.linalg.svd(P_a)[2][-1]
    e = P_b @ C_a
    ex = np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]])
    F = ex @ P_b @ np.linalg.pinv(P_a)
    F /= np.linalg.norm(F)
    return F * np.sign(F.flat[np.abs(F).argmax()])


def strecha_projection(name: str, pixel_shift: float = 0.0) -> np.ndarray:
    """P = K [R^T | -R^T C] of a published camera; ``pixel_shift`` added to the principal point."""
    K, R, C = strecha_camera(name)
    K = K.copy()
    K[0, 2] += pixel_shift
    K[1, 2] += pixel_shift
    return K @ np.c_[R.T, -R.T @ C]


def same_up_to_sign(A, B, tol) -> bool:
    A, B = np.asarray(A, float), np.asarray(B, float)
    return min(np.abs(A - B).max(), np.abs(A + B).max()) < tol


def mean_line_distance(F, x_a, x_b) -> np.ndarray:
    """fviz's SED written out independently: the mean of d(x_b, F x_a) and d(x_a, F^T x_b), pixels."""
    h = lambda x: np.c_[x, np.ones(len(x))]  # noqa: E731
    lb, la = h(x_a) @ np.asarray(F).T, h(x_b) @ np.asarray(F)
    r = np.abs(np.sum(h(x_b) * lb, 1))
    return 0.5 * (r / np.hypot(lb[:, 0], lb[:, 1]) + r / np.hypot(la[:, 0], la[:, 1]))
