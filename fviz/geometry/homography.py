"""How much of a set of correspondences one homography explains (a plane, or a pure rotation): the evidence that F
is poorly determined. OpenCV's RANSAC, seeded."""

from __future__ import annotations

import numpy as np

HOMOGRAPHY_PX = 2.0
MIN_FIT = 8  # fewer correspondences than this: no homography is fitted


def homography_fraction(x_a: np.ndarray, x_b: np.ndarray) -> float:
    """Fraction of the correspondences one RANSAC homography explains (NaN for fewer than MIN_FIT)."""
    import cv2

    if len(x_a) < MIN_FIT:
        return float("nan")
    cv2.setRNGSeed(0)
    H, mask = cv2.findHomography(x_a.astype(np.float64), x_b.astype(np.float64), cv2.RANSAC, HOMOGRAPHY_PX)
    return float("nan") if H is None else float(mask.ravel().astype(bool).mean())
