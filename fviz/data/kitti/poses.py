"""Camera-0 poses of a KITTI sequence: odometry's poses file, or a raw drive's oxts GPS/IMU packets as pykitti and the
KITTI devkit derive them (:func:`oxts_imu_poses`, :func:`fviz.data.kitti.calib.cam0_from_imu`), checked before use."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fviz.data.kitti.calib import cam0_from_imu
from fviz.data.kitti.files import read_text
from fviz.errors import FvizError

# Poses fviz trusts: rotation blocks orthonormal to ROTATION_TOL (max |R^T R - I|; KITTI's printed digits
# give ~1e-6), det(R) = +1, translations below MAX_TRANSLATION_M.
ROTATION_TOL = 1e-3
MAX_TRANSLATION_M = 1e6


def check_poses(T: np.ndarray, path: Path) -> np.ndarray:
    """(N, 4, 4) poses, checked: finite, rotations orthonormal with det +1 (ROTATION_TOL), translations
    below MAX_TRANSLATION_M. Raises FvizError naming the file and line of the first bad pose."""
    R, t = T[:, :3, :3], T[:, :3, 3]
    with np.errstate(all="ignore"):
        ortho = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
        det = np.linalg.det(np.nan_to_num(R))
    checks = ((~np.isfinite(T).all(axis=(1, 2)), "NaN or infinite numbers"),
              (~(np.abs(t) < MAX_TRANSLATION_M).all(axis=1), f"a translation of {MAX_TRANSLATION_M:g} m or more"),
              (~(ortho <= ROTATION_TOL), f"the rotation block is not a rotation (|R^T R - I| > {ROTATION_TOL:g})"),
              (~(det > 0), "the rotation block is a reflection (det < 0)"))
    for bad, why in checks:
        if bad.any():
            line = int(np.nonzero(bad)[0][0]) + 1
            raise FvizError(f"poses {path}:{line}: {why}")
    return T


def read_poses(path: Path) -> np.ndarray:
    """(N, 4, 4) camera 0 -> world of an odometry poses file (one 3x4 row-major [R | t] per line), checked."""
    text = read_text(path, "poses")
    try:
        rows = np.loadtxt(text.splitlines(), dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise FvizError(f"poses {path}: cannot parse ({exc})") from None
    if rows.shape[1] != 12:
        raise FvizError(f"poses {path}: {rows.shape[1]} numbers per line, expected 12")
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :] = rows.reshape(-1, 3, 4)
    return check_poses(T, path)


# ----------------------------------------------------------------------------------------------- oxts (raw drives)

OXTS_FIELDS = 30  # lat lon alt roll pitch yaw vn ve vf vl vu ax ay az af al au wx wy wz wf wl wu pos_acc vel_acc ...
EARTH_RADIUS_M = 6378137.0  # the KITTI devkit's (and pykitti's) radius of the Mercator projection
# How far a raw temporal pair's ground truth can be trusted (px): the OXTS RT3003's poses (0.03 deg roll/pitch,
# 0.1 deg heading, cm-level RTK positions where available) are coarser than odometry's; see the README's figures.
OXTS_GT_ACCURACY_PX = 5.0


def read_oxts(path: Path) -> np.ndarray:
    """(30,) numbers of one oxts packet (oxts/dataformat.txt); a one-line FvizError naming file and line otherwise."""
    lines = [(n, line) for n, line in enumerate(read_text(path, "oxts packet").splitlines(), 1) if line.strip()]
    if len(lines) != 1:
        raise FvizError(f"oxts packet {path}: {len(lines)} lines of numbers, expected 1")
    n, line = lines[0]
    try:
        values = np.array(line.split(), dtype=np.float64)
    except ValueError:
        raise FvizError(f"oxts packet {path}:{n}: cannot parse the numbers") from None
    if values.size != OXTS_FIELDS:
        raise FvizError(f"oxts packet {path}:{n}: {values.size} numbers, expected {OXTS_FIELDS}")
    if not np.isfinite(values).all():
        raise FvizError(f"oxts packet {path}:{n}: NaN or infinite numbers")
    return values


def _rotation_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll): the oxts unit's orientation (x forward, y left, z up) in east-north-up."""
    c, s = np.cos([roll, pitch, yaw]), np.sin([roll, pitch, yaw])
    Rx = np.array([[1, 0, 0], [0, c[0], -s[0]], [0, s[0], c[0]]])
    Ry = np.array([[c[1], 0, s[1]], [0, 1, 0], [-s[1], 0, c[1]]])
    Rz = np.array([[c[2], -s[2], 0], [s[2], c[2], 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def oxts_imu_poses(packets: np.ndarray) -> np.ndarray:
    """(N, 30) oxts packets -> (N, 4, 4) IMU -> world, T_w_imu as pykitti and the devkit compute it: Mercator
    positions with the scale cos(lat) of the first packet, orientation Rz(yaw) Ry(pitch) Rx(roll).  World: east,
    north, up (m) from the first packet's position (as pykitti: keeps the ~5e6 m northings out of later products)."""
    lat, lon, alt = packets[:, 0], packets[:, 1], packets[:, 2]
    scale = np.cos(lat[0] * np.pi / 180)
    T = np.tile(np.eye(4), (len(packets), 1, 1))
    T[:, 0, 3] = scale * lon * np.pi * EARTH_RADIUS_M / 180
    T[:, 1, 3] = scale * EARTH_RADIUS_M * np.log(np.tan((90 + lat) * np.pi / 360))
    T[:, 2, 3] = alt
    T[:, :3, 3] -= T[0, :3, 3].copy()
    T[:, :3, :3] = [_rotation_rpy(*p[3:6]) for p in packets]
    return T


def oxts_camera_poses(oxts_dir: Path, date_dir: Path, num_frames: int) -> np.ndarray:
    """(N, 4, 4) rectified camera 0 -> world of a raw drive, world = camera 0 at the first frame with a packet;
    NaN for frames without one.  N covers ``num_frames`` and every packet."""
    if not oxts_dir.is_dir():
        raise FvizError(f"temporal pairs need ground-truth poses: missing oxts folder {oxts_dir} (use --pair stereo)")
    files = {int(p.stem): p for p in oxts_dir.glob("*.txt") if p.stem.isdigit()}
    if not files:
        raise FvizError(f"temporal pairs need ground-truth poses: no oxts packets in {oxts_dir} (use --pair stereo)")
    frames = sorted(files)
    T_w_cam = oxts_imu_poses(np.stack([read_oxts(files[f]) for f in frames])) @ np.linalg.inv(cam0_from_imu(date_dir))
    poses = np.full((max(num_frames, frames[-1] + 1), 4, 4), np.nan)
    poses[frames] = np.linalg.inv(T_w_cam[0]) @ T_w_cam
    return poses

