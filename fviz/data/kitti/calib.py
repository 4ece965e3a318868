"""KITTI's calibration files: the rectified projections P_i = K [I | t_i] of both layouts, the unrectified cameras
of a raw drive (the frame the paper's F lives in) and the IMU -> camera 0 transform that turns oxts poses into
camera poses."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fviz.data.kitti.files import read_text
from fviz.errors import FvizError
from fviz.geometry import fundamental_from_motion, normalize


def _read_key_values(path: Path, what: str) -> dict[str, np.ndarray]:
    out = {}
    for n, line in enumerate(read_text(path, what).splitlines(), 1):
        if ":" not in line:
            continue
        key, _, rest = line.partition(":")
        try:
            out[key.strip()] = np.array(rest.split(), dtype=np.float64)
        except ValueError:
            if key.strip() != "calib_time":
                raise FvizError(f"{what} {path}:{n}: cannot parse the numbers of '{key.strip()}'") from None
    return out


def _entry(values: dict[str, np.ndarray], key: str, size: int, path: Path) -> np.ndarray:
    """The ``size`` finite numbers of a calibration entry; a one-line FvizError naming file and entry otherwise."""
    if key not in values:
        raise FvizError(f"calibration {path}: no '{key}' entry")
    if values[key].size != size:
        raise FvizError(f"calibration {path}: '{key}' has {values[key].size} numbers, expected {size}")
    if not np.isfinite(values[key]).all():
        raise FvizError(f"calibration {path}: '{key}' holds NaN or infinite numbers")
    return values[key]


def _projection(values: dict[str, np.ndarray], key: str, path: Path) -> np.ndarray:
    P = _entry(values, key, 12, path).reshape(3, 4)
    if not (P[0, 0] > 0 and P[1, 1] > 0 and P[2, 2] != 0):
        raise FvizError(f"calibration {path}: '{key}' is not a rectified projection K [I | t] (focal lengths > 0)")
    return P


def rectified_projections(calib: Path, key: str) -> dict[int, np.ndarray]:
    """Cameras 0..3 of a calibration file, ``key`` naming each entry ("P{cam}", "P_rect_0{cam}"); camera 0 required."""
    values = _read_key_values(calib, "calibration")
    projections = {cam: _projection(values, key.format(cam=cam), calib) for cam in range(4) if key.format(cam=cam) in values}
    if 0 not in projections:
        raise FvizError(f"calibration {calib}: no '{key.format(cam=0)}' entry")
    return projections


def decompose(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rectified P = K [I | t] -> (K, t)."""
    K = P[:, :3].copy()
    return K, np.linalg.solve(K, P[:, 3])


def _rigid(path: Path) -> np.ndarray:
    """4x4 [R | T] of a raw calibration file (calib_imu_to_velo.txt, calib_velo_to_cam.txt)."""
    values = _read_key_values(path, "calibration")
    T = np.eye(4)
    T[:3, :3] = _entry(values, "R", 9, path).reshape(3, 3)
    T[:3, 3] = _entry(values, "T", 3, path)
    return T


def cam0_from_imu(date_dir: Path) -> np.ndarray:
    """4x4 T_cam0rect_imu = R_rect_00 @ T_velo_to_cam @ T_imu_to_velo from a raw drive's date folder."""
    cam_to_cam = date_dir / "calib_cam_to_cam.txt"
    R_rect = np.eye(4)
    R_rect[:3, :3] = _entry(_read_key_values(cam_to_cam, "calibration"), "R_rect_00", 9, cam_to_cam).reshape(3, 3)
    return R_rect @ _rigid(date_dir / "calib_velo_to_cam.txt") @ _rigid(date_dir / "calib_imu_to_velo.txt")


# ----------------------------------------------------------------------------------------------- unrectified frame


@dataclass(frozen=True)
class RawCamera:
    """One camera of a raw drive before rectification (``calib_cam_to_cam.txt``), distortion left out.

    K: (3, 3) intrinsics; R, T: camera 0 -> this camera (X_cam = R X_0 + T, metres); size: (w, h) of the
    unrectified image; H: (3, 3) rectified pixel -> unrectified (undistorted) pixel, K R_rect^T P_rect[:, :3]^-1
    (a rotation about the camera centre, so exact at every depth); rect_size: (w, h) of the rectified image.
    """

    K: np.ndarray
    R: np.ndarray
    T: np.ndarray
    size: tuple[int, int]
    H: np.ndarray
    rect_size: tuple[int, int]


def raw_cameras(calib: Path) -> dict[int, RawCamera]:
    """The unrectified cameras of a raw drive's ``calib_cam_to_cam.txt``: the frame the paper's F lives in
    (its F is built from K, R, T and has F33 != 0, unlike rectified stereo)."""
    values = _read_key_values(calib, "calibration")
    cams = {}
    for cam in range(4):
        if f"K_0{cam}" not in values:
            continue
        K = _entry(values, f"K_0{cam}", 9, calib).reshape(3, 3)
        R = _entry(values, f"R_0{cam}", 9, calib).reshape(3, 3)
        T = _entry(values, f"T_0{cam}", 3, calib)
        w, h = _entry(values, f"S_0{cam}", 2, calib)
        R_rect = _entry(values, f"R_rect_0{cam}", 9, calib).reshape(3, 3)
        P_rect = _projection(values, f"P_rect_0{cam}", calib)
        rw, rh = _entry(values, f"S_rect_0{cam}", 2, calib)
        cams[cam] = RawCamera(K, R, T, (int(w), int(h)), K @ R_rect.T @ np.linalg.inv(P_rect[:, :3]), (int(rw), int(rh)))
    if 0 not in cams:
        raise FvizError(f"calibration {calib}: no 'K_00' entry (not a raw drive's calib_cam_to_cam.txt)")
    return cams


def unrectified_fundamental(a: RawCamera, b: RawCamera) -> np.ndarray:
    """F between two unrectified cameras straight from K, R, T (``x_b^T F x_a = 0``), unit Frobenius norm."""
    R = b.R @ a.R.T
    return normalize(fundamental_from_motion(a.K, b.K, R, b.T - R @ a.T), "fbn")
