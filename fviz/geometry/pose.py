"""Relative pose from F and the field's pose errors (SuperGlue / LightGlue / glue-factory).

Motion convention as everywhere in fviz: X_b = R X_a + t, and x_b^T F x_a = 0 in pixels, so the
essential matrix is E = K_b^T F K_a (x̂_b^T E x̂_a = 0 with x̂ = K^-1 x).
"""

from __future__ import annotations

import numpy as np

AUC_THRESHOLDS_DEG = (5.0, 10.0, 20.0)
MIN_POSE_POINTS = 5


def essential_from_fundamental(F: np.ndarray, K_a: np.ndarray, K_b: np.ndarray) -> np.ndarray:
    """E = K_b^T F K_a.  (..., 3, 3) x3 -> (..., 3, 3), not normalized."""
    return np.swapaxes(np.asarray(K_b, np.float64), -1, -2) @ np.asarray(F, np.float64) @ np.asarray(K_a, np.float64)


def _normalized(K: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) -> normalized image coordinates (N, 2) of camera K."""
    p = np.c_[np.asarray(x, np.float64), np.ones(len(x))] @ np.linalg.inv(K).T
    return p[:, :2] / p[:, 2:]


def recover_pose(F: np.ndarray, K_a: np.ndarray, K_b: np.ndarray, x_a: np.ndarray, x_b: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """(R (3, 3), t (3,) unit) of the decomposition of E = K_b^T F K_a that puts the most of the
    correspondences (N, 2) in front of both cameras (``cv2.recoverPose`` on normalized coordinates).
    None with fewer than MIN_POSE_POINTS correspondences or when no decomposition has a point in front."""
    import cv2

    if len(x_a) < MIN_POSE_POINTS:
        return None
    E = essential_from_fundamental(F, K_a, K_b)
    E = E / np.linalg.norm(E)
    n_front, R, t, _ = cv2.recoverPose(E, _normalized(K_a, x_a), _normalized(K_b, x_b), np.eye(3))
    if n_front == 0:
        return None
    t = t.ravel()
    return R, t / np.linalg.norm(t)


def essential_decomposition(F: np.ndarray, K_a: np.ndarray, K_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(R1, R2, t) of E = K_b^T F K_a = U diag(1, 1, 0) V^T: its two rotations U W V^T and U W^T V^T and its
    translation direction U[:, 2] (sign unknown; Hartley & Zisserman 9.6.2). float64 throughout: OpenCV's
    decomposeEssentialMat was off by 0.017 deg on exact KITTI ground truth."""
    U, _, Vt = np.linalg.svd(essential_from_fundamental(F, K_a, K_b))
    U, Vt = U * np.sign(np.linalg.det(U)), Vt * np.sign(np.linalg.det(Vt))
    W = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return U @ W @ Vt, U @ W.T @ Vt, U[:, 2]


def small_motion(F: np.ndarray, K_a: np.ndarray, K_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of E = K_b^T F K_a = [t]x R whose rotation is the one nearer the identity (consecutive frames
    turn little), t unit, its sign unknown."""
    R1, R2, t = essential_decomposition(F, K_a, K_b)
    return min((R1, R2), key=rotation_angle_deg), t


def mean_motion_f(Fs: list[np.ndarray], K_a: np.ndarray, K_b: np.ndarray, yaw_gain: float = 1.0) -> np.ndarray:
    """F of the mean of the motions (:func:`small_motion`) of several F's of one pair: the rotations averaged
    (the nearest rotation to their mean), the translations' signs aligned with the first's, then averaged.
    (3, 3) each -> (3, 3), unit Frobenius norm. Unlike a mean of the F's, it keeps each F's rotation however
    far their epipoles lie apart. ``yaw_gain`` multiplies the mean rotation's yaw (:func:`scale_yaw`)."""
    from fviz.geometry.fundamental import fundamental_from_motion

    motions = [small_motion(F, K_a, K_b) for F in Fs]
    t0 = motions[0][1]
    t = sum(t if t @ t0 >= 0 else -t for _, t in motions)
    R = scale_yaw(nearest_rotation(sum(R for R, _ in motions) / len(motions)), yaw_gain)
    F = fundamental_from_motion(K_a, K_b, R, t / np.linalg.norm(t))
    return F / np.linalg.norm(F)


def yaw_deg(R: np.ndarray) -> np.ndarray:
    """Rotation about the camera's y axis (down), degrees: atan2(R[0, 2], R[2, 2]); positive turns the optical
    axis towards +x.  (..., 3, 3) -> (...)."""
    R = np.asarray(R, np.float64)
    return np.degrees(np.arctan2(R[..., 0, 2], R[..., 2, 2]))


def scale_yaw(R: np.ndarray, gain: float) -> np.ndarray:
    """R turned about the camera's y axis until its yaw is ``gain`` times R's: R_y((gain - 1) psi) R, psi =
    :func:`yaw_deg` (R_y(a) R has yaw psi + a exactly; pitch and roll are kept).  (3, 3) -> (3, 3)."""
    if gain == 1.0:
        return np.asarray(R, np.float64)
    a = np.radians((gain - 1.0) * yaw_deg(R))
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]) @ np.asarray(R, np.float64)


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation closest to M in Frobenius norm, by SVD (KITTI's poses are printed to ~1e-6: their R^T R
    misses I by enough for a 0.02 deg error floor).  (..., 3, 3) -> (..., 3, 3)."""
    U, _, Vt = np.linalg.svd(np.asarray(M, np.float64))
    d = np.ones(U.shape[:-1])
    d[..., 2] = np.linalg.det(U @ Vt)
    return (U * d[..., None, :]) @ Vt


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Rotation angle of R, degrees in [0, 180]: atan2(|axis part|, (tr R - 1) / 2), which keeps its precision
    for small angles where arccos((tr R - 1) / 2) loses it (1e-3 deg).  (..., 3, 3) -> (...)."""
    R = np.asarray(R, np.float64)
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    return np.degrees(np.arctan2(np.linalg.norm(w, axis=-1) / 2.0, c))


def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> np.ndarray:
    """Angle of R_est^T R_gt, degrees.  (..., 3, 3) x2 -> (...)."""
    return rotation_angle_deg(np.swapaxes(np.asarray(R_est, np.float64), -1, -2) @ np.asarray(R_gt, np.float64))


def translation_error_deg(t_est: np.ndarray, t_gt: np.ndarray) -> np.ndarray:
    """Angle between t_est and t_gt as min(e, 180 - e), degrees in [0, 90]: F fixes neither the sign nor
    the scale of t. A zero t_gt (pure rotation: no direction to compare) gives 0, as glue-factory's
    ``relative_pose_error`` does below its ``ignore_gt_t_thr``.  (..., 3) x2 -> (...)."""
    t_est, t_gt = np.asarray(t_est, np.float64), np.asarray(t_gt, np.float64)
    n_est, n_gt = np.linalg.norm(t_est, axis=-1), np.linalg.norm(t_gt, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.sum(t_est * t_gt, axis=-1) / (n_est * n_gt)
    e = np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))
    return np.where(n_gt > 0, np.minimum(e, 180.0 - e), 0.0)


def pose_auc(errors_deg, thresholds=AUC_THRESHOLDS_DEG) -> list[float]:
    """Area under the recall-vs-error curve up to each threshold, divided by it (SuperGlue's ``pose_auc``,
    which LightGlue and glue-factory use): errors sorted, recall steps of 1/N from (0, 0), the curve
    held flat from the last error below the threshold to the threshold. NaN errors (failures) count
    as infinite: they stay in N but never enter the curve. An empty list gives NaN."""
    e = np.asarray(errors_deg, np.float64).ravel()
    if len(e) == 0:
        return [float("nan")] * len(thresholds)
    e = np.sort(np.where(np.isnan(e), np.inf, e))
    recall = np.r_[0.0, np.arange(1, len(e) + 1) / len(e)]
    e = np.r_[0.0, e]
    out = []
    for th in thresholds:
        last = int(np.searchsorted(e, th))
        r = np.r_[recall[:last], recall[last - 1]]
        x = np.r_[e[:last], th]
        out.append(float(np.sum((x[1:] - x[:-1]) * (r[1:] + r[:-1]) / 2.0) / th))
    return out
