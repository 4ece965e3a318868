"""KITTI in its two official layouts, auto-detected under ``--kitti-root``.

odometry:  [odometry/]dataset/sequences/NN/{calib.txt, image_0..3/NNNNNN.png},  [odometry/]dataset/poses/NN.txt
raw:       [raw/]DATE/calib_{cam_to_cam,imu_to_velo,velo_to_cam}.txt,  [raw/]DATE/DATE_drive_NNNN_sync/image_0X/data/NNNNNNNNNN.png,
           [raw/]DATE/DATE_drive_NNNN_sync/oxts/data/NNNNNNNNNN.txt

Both are rectified: every camera's projection matrix is P_i = K [I | t_i] in the rectified frame of
camera 0, so a pair's ground truth follows from two projection matrices of one world frame.
Stereo pairs (two cameras, one frame) work in both layouts. Temporal pairs (one camera, frames
t -> t+k) need camera-0 poses (camera 0 -> world): odometry's poses file, or, in a raw drive, the oxts
GPS/IMU packets of both frames, as pykitti and the KITTI devkit derive them (:func:`oxts_imu_poses`,
:func:`cam0_from_imu`). GPS/IMU poses are less accurate than odometry's: a raw temporal pair's
``gt_accuracy_px`` is :data:`OXTS_GT_ACCURACY_PX`.
"""

from __future__ import annotations

import errno
import os
import re
from dataclasses import dataclass
import functools
from functools import cached_property
from pathlib import Path

import numpy as np

from fviz.data.pair import LazyImage, Pair, PairId
from fviz.errors import FvizError
from fviz.geometry import fundamental_from_motion, fundamental_from_projections, normalize

PAIR_KINDS = ("stereo", "temporal")
# How far the ground truth can be trusted (README of the sample data): calibration vs poses.
GT_ACCURACY_PX = {"stereo": 0.5, "temporal": 3.0}
# Without --cams: the gray cameras, or the colour ones where the gray images are absent (colour download).
DEFAULT_CAMS = {"stereo": ((0, 1), (2, 3)), "temporal": ((0, 0), (2, 2))}
# Poses fviz trusts: rotation blocks orthonormal to ROTATION_TOL (max |R^T R - I|; KITTI's printed digits
# give ~1e-6), det(R) = +1, translations below MAX_TRANSLATION_M; a pair moves by at least MIN_BASELINE_M.
ROTATION_TOL = 1e-3
MAX_TRANSLATION_M = 1e6
MIN_BASELINE_M = 1e-6


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


def check_file(path: Path, what: str) -> Path:
    """``path`` if it is a file; else a one-line FvizError saying what is wrong with it."""
    if path.is_dir():
        raise FvizError(f"{what} {path}: a folder, not a file")
    if not path.exists():
        if path.is_symlink():
            try:
                os.stat(path)
            except OSError as exc:
                why = "a symlink loop" if exc.errno == errno.ELOOP else f"a symlink to the missing {os.readlink(path)}"
                raise FvizError(f"{what} {path}: {why}") from None
        raise FvizError(f"missing {what}: {path}")
    return path


def read_text(path: Path, what: str) -> str:
    try:
        return check_file(path, what).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise FvizError(f"cannot read {what} {path} ({getattr(exc, 'strerror', None) or exc})") from None


def read_image(path: Path) -> np.ndarray:
    """uint8 (H, W) gray or (H, W, 3) RGB; a one-line FvizError naming the file otherwise."""
    import cv2

    check_file(path, "image")
    if not os.access(path, os.R_OK):
        raise FvizError(f"cannot read image {path} (permission denied)")
    from fviz.quiet import native_stderr_silenced

    with native_stderr_silenced():  # libpng's own "libpng error: ..." line: fviz's error says it
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise FvizError(f"unreadable or corrupt image: {path}")
    if img.dtype != np.uint8:
        img = cv2.convertScaleAbs(img, alpha=255.0 / max(float(img.max()), 1.0))
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return img


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


def _projections(calib: Path, key: str) -> dict[int, np.ndarray]:
    """Cameras 0..3 of a calibration file, ``key`` naming each entry ("P{cam}", "P_rect_0{cam}"); camera 0 required."""
    values = _read_key_values(calib, "calibration")
    projections = {cam: _projection(values, key.format(cam=cam), calib) for cam in range(4) if key.format(cam=cam) in values}
    if 0 not in projections:
        raise FvizError(f"calibration {calib}: no '{key.format(cam=0)}' entry")
    return projections


def _decompose(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rectified P = K [I | t] -> (K, t)."""
    K = P[:, :3].copy()
    return K, np.linalg.solve(K, P[:, 3])


# ----------------------------------------------------------------------------------------------- unrectified frame


@dataclass(frozen=True)
class RawCamera:
    """One camera of a raw drive before rectification (``calib_cam_to_cam.txt``), distortion left out.

    K: (3, 3) intrinsics; R, T: camera 0 -> this camera (X_cam = R X_0 + T, metres); size: (w, h) of the
    unrectified image; H: (3, 3) rectified pixel -> unrectified (undistorted) pixel, K R_rect^T P_rect[:, :3]^-1
    (a rotation about the camera centre, so exact at every depth).
    """

    K: np.ndarray
    R: np.ndarray
    T: np.ndarray
    size: tuple[int, int]
    H: np.ndarray


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
        cams[cam] = RawCamera(K, R, T, (int(w), int(h)), K @ R_rect.T @ np.linalg.inv(P_rect[:, :3]))
    if 0 not in cams:
        raise FvizError(f"calibration {calib}: no 'K_00' entry (not a raw drive's calib_cam_to_cam.txt)")
    return cams


def unrectified_fundamental(a: RawCamera, b: RawCamera) -> np.ndarray:
    """F between two unrectified cameras straight from K, R, T (``x_b^T F x_a = 0``), unit Frobenius norm."""
    R = b.R @ a.R.T
    return normalize(fundamental_from_motion(a.K, b.K, R, b.T - R @ a.T), "fbn")


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


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_shape(path: Path) -> tuple[int, ...] | None:
    """The shape :func:`read_image` gives an 8- or 16-bit gray or RGB PNG, from its header alone ((H, W) or
    (H, W, 3)); None for any other file, or a header whose CRC does not match (read it whole)."""
    import zlib

    try:
        with open(path, "rb") as f:
            head = f.read(33)
    except OSError:
        return None
    if len(head) < 33 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        return None
    if zlib.crc32(head[12:29]) != int.from_bytes(head[29:33], "big"):  # a damaged header: decode now, which names it
        return None
    width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    depth, colour = head[24], head[25]
    if width == 0 or height == 0 or depth not in (8, 16) or colour not in (0, 2):  # gray, RGB
        return None
    return (height, width) if colour == 0 else (height, width, 3)


def lazy_image(path: Path) -> "np.ndarray | LazyImage":
    """:func:`read_image` of ``path`` deferred to the first read of the pixels (a PNG whose header gives its
    shape), else read now. A missing or unreadable file is an error now either way."""
    check_file(path, "image")
    if not os.access(path, os.R_OK):
        raise FvizError(f"cannot read image {path} (permission denied)")
    shape = png_shape(path)
    return read_image(path) if shape is None else LazyImage(functools.partial(read_image, path), shape)  # picklable


@dataclass
class KittiSequence:
    """One odometry sequence or one raw drive: frames, cameras, poses, and pairs."""

    source: str  # "odometry" | "raw"
    name: str  # "00" | "2011_09_26_drive_0001"
    root: Path  # the --kitti-root the user gave
    image_dirs: dict[int, Path]
    calib_path: Path
    calib_key: str  # "P{cam}" | "P_rect_0{cam}"
    projections: dict[int, np.ndarray]
    poses_path: Path | None = None  # odometry's poses file
    oxts_dir: Path | None = None  # a raw drive's oxts/data

    def image_path(self, cam: int, frame: int) -> Path:
        digits = 6 if self.source == "odometry" else 10
        return self.image_dirs[cam] / f"{frame:0{digits}d}.png"

    @cached_property
    def frame_counts(self) -> dict[int, int]:
        """camera -> last frame number + 1 of its images (0 without any): what each folder holds."""
        counts = {}
        for cam, d in self.image_dirs.items():
            frames = [int(p.stem) for p in d.glob("*.png") if p.stem.isdigit()] if d.is_dir() else []
            counts[cam] = max(frames) + 1 if frames else 0
        return counts

    @property
    def num_frames(self) -> int:
        """Frames of the camera with the most images (a selection counts those of its own cameras)."""
        return max(self.frame_counts.values(), default=0)

    def image_folder(self, cam: int) -> str:
        """The folder name users know a camera by: image_2 (odometry), image_02 (raw, whose images are in data/)."""
        d = self.image_dirs[cam]
        return d.parent.name if self.source == "raw" else d.name

    def frames_of(self, cams: tuple[int, ...]) -> int:
        """Frames 0..N-1 of a pair's cameras: a frame missing in one of them is that pair's (recorded) error."""
        return max(self.frame_counts[c] for c in cams)

    @cached_property
    def poses(self) -> np.ndarray:
        """(N, 4, 4) camera-0 -> world transforms, one per frame.

        Raw drives: from every oxts packet at once (:func:`oxts_camera_poses`; NaN for a frame without one, which
        :meth:`pose` names when a pair needs it); a corrupt packet is an error for the whole drive, as a NaN in an
        odometry poses file is."""
        if self.oxts_dir is not None:
            return oxts_camera_poses(self.oxts_dir, self.calib_path.parent, self.num_frames)
        if self.poses_path is None:
            raise FvizError(
                f"temporal pairs need ground-truth poses, which the {self.source} layout of {self.name} lacks "
                "(use --pair stereo, or an odometry sequence)"
            )
        text = read_text(self.poses_path, "poses")
        try:
            rows = np.loadtxt(text.splitlines(), dtype=np.float64, ndmin=2)
        except ValueError as exc:
            raise FvizError(f"poses {self.poses_path}: cannot parse ({exc})") from None
        if rows.shape[1] != 12:
            raise FvizError(f"poses {self.poses_path}: {rows.shape[1]} numbers per line, expected 12")
        T = np.tile(np.eye(4), (len(rows), 1, 1))
        T[:, :3, :] = rows.reshape(-1, 3, 4)
        return check_poses(T, self.poses_path)

    @property
    def pose_frames(self) -> set[int]:
        """Frames with a ground-truth pose; none where the layout has no poses file or oxts folder at all."""
        source = self.oxts_dir or self.poses_path
        if source is None or not source.exists():
            return set()
        return {int(f) for f in np.flatnonzero(np.isfinite(self.poses).all(axis=(1, 2)))}

    def pose(self, frame: int) -> np.ndarray:
        """4x4 camera 0 -> world at ``frame``; a one-line FvizError naming the missing poses line or oxts packet."""
        T = self.poses
        if frame < len(T) and np.isfinite(T[frame]).all():
            return T[frame]
        if self.oxts_dir is not None:
            raise FvizError(f"missing oxts packet of frame {frame}: {self.oxts_dir / f'{frame:010d}.txt'}")
        raise FvizError(f"poses {self.poses_path}: no pose for frame {frame} ({len(T)} lines)")

    def gt_accuracy_px(self, kind: str) -> float:
        """How far a pair's ground truth can be trusted: calibration, odometry poses, or GPS/IMU (oxts)."""
        return OXTS_GT_ACCURACY_PX if kind == "temporal" and self.oxts_dir is not None else GT_ACCURACY_PX[kind]

    def check_frame(self, frame: int, cams: tuple[int, ...], field: str = "--frame") -> None:
        n = self.frames_of(cams)
        if not 0 <= frame < n:
            folders = ", ".join(sorted({self.image_folder(c) for c in cams}))
            raise FvizError(f"{field} {frame} out of range: {self.source} {self.name} has frames 0..{n - 1} in {folders}")

    def check_cam(self, cam: int) -> None:
        if cam not in self.projections:
            entries = ", ".join(self.calib_key.format(cam=c) for c in sorted(self.projections))
            raise FvizError(f"--cams: camera {cam} has no '{self.calib_key.format(cam=cam)}' entry in {self.calib_path} "
                            f"(it has {entries})")
        if self.frame_counts[cam] == 0:
            d = self.image_dirs[cam]
            with_images = ", ".join(str(c) for c, n in sorted(self.frame_counts.items()) if n) or "none"
            what = "no images in" if d.is_dir() else "missing image folder"
            raise FvizError(f"--cams: {what} {d} (cameras with images here: {with_images})")

    def default_cams(self, kind: str) -> tuple[int, int]:
        """The gray cameras, or the colour ones when only those have images (as in KITTI's colour download)."""
        options = DEFAULT_CAMS[kind]
        usable = [c for c in options if all(self.frame_counts.get(cam, 0) for cam in c)]
        return (usable or options)[0]

    def pair_id(self, frame: int, kind: str = "stereo", step: int = 1, cams: tuple[int, int] | None = None) -> PairId:
        """Validate a selection and name its pair (no image is read)."""
        if kind not in PAIR_KINDS:
            raise FvizError(f"--pair {kind!r}: choose one of {', '.join(PAIR_KINDS)}")
        cam_a, cam_b = cams or self.default_cams(kind)
        for cam in (cam_a, cam_b):
            self.check_cam(cam)
        if kind == "stereo":
            if cam_a == cam_b:
                raise FvizError(f"--cams {cam_a},{cam_b}: a stereo pair needs two different cameras")
            frame_b = frame
        else:
            if step < 1:
                raise FvizError(f"--step {step}: must be >= 1")
            frame_b = frame + step
        self.check_frame(frame, (cam_a, cam_b))
        self.check_frame(frame_b, (cam_a, cam_b), "--frame + --step")
        return PairId(self.source, self.name, kind, frame, frame_b, cam_a, cam_b, str(self.root))

    def extrinsics(self, cam: int, frame: int, ref_frame: int) -> np.ndarray:
        """4x4 map from camera 0 at ``ref_frame`` to camera ``cam`` at ``frame``."""
        _, t = _decompose(self.projections[cam])
        E = np.eye(4)
        E[:3, 3] = t
        if frame != ref_frame:
            T_ref = self.pose(ref_frame)
            E = E @ np.linalg.inv(self.pose(frame)) @ T_ref
        return E

    def pair(self, frame: int, kind: str = "stereo", step: int = 1, cams: tuple[int, int] | None = None) -> Pair:
        """Load a pair with its ground truth (x_b^T F_gt x_a = 0, pixels)."""
        return self.load(self.pair_id(frame, kind, step, cams))

    def ground_truth(self, pid: PairId) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(K_a, K_b, R, t, F_gt) of a pair from calibration and poses alone: no image is read."""
        E_a = self.extrinsics(pid.cam_a, pid.frame_a, pid.frame_a)
        E_b = self.extrinsics(pid.cam_b, pid.frame_b, pid.frame_a)
        K_a, _ = _decompose(self.projections[pid.cam_a])
        K_b, _ = _decompose(self.projections[pid.cam_b])
        T_ab = E_b @ np.linalg.inv(E_a)
        if not np.linalg.norm(T_ab[:3, 3]) >= MIN_BASELINE_M:
            where = f"poses {self.oxts_dir or self.poses_path}: frames {pid.frame_a} and {pid.frame_b}" if pid.frame_a != pid.frame_b \
                else f"{self.calib_path}: cameras {pid.cam_a} and {pid.cam_b}"
            raise FvizError(f"{where} are at the same place (baseline {np.linalg.norm(T_ab[:3, 3]):.2g} m): "
                            "a pair without motion has no fundamental matrix")
        F = fundamental_from_projections(K_a @ E_a[:3], K_b @ E_b[:3])
        return K_a, K_b, T_ab[:3, :3], T_ab[:3, 3], F

    def load(self, pid: PairId) -> Pair:
        K_a, K_b, R, t, F = self.ground_truth(pid)
        path_a, path_b = self.image_path(pid.cam_a, pid.frame_a), self.image_path(pid.cam_b, pid.frame_b)
        image_a, image_b = lazy_image(path_a), lazy_image(path_b)  # decoded if features are detected
        notes = []
        if image_a.ndim != image_b.ndim:
            image_a, image_b, note = _as_gray(read_image(path_a), read_image(path_b), pid)
            notes.append(note)
        if image_a.shape[:2] != image_b.shape[:2]:
            raise FvizError(
                f"images of different sizes in a {pid.kind} pair: {path_a} is {image_a.shape[1]}x{image_a.shape[0]}, "
                f"{path_b} is {image_b.shape[1]}x{image_b.shape[0]}"
            )
        return Pair(
            id=pid, image_a=image_a, image_b=image_b, K_a=K_a, K_b=K_b, R=R, t=t, F_gt=F,
            gt_accuracy_px=self.gt_accuracy_px(pid.kind), extra={"path_a": str(path_a), "path_b": str(path_b)}, notes=notes,
        )


def _as_gray(image_a: np.ndarray, image_b: np.ndarray, pid: PairId) -> tuple[np.ndarray, np.ndarray, str]:
    """A gray/colour pair (e.g. cameras 0 and 2) as two gray images, and the note that says so.

    Features are detected on gray images anyway; this keeps the recording and the deep models honest about it.
    """
    import cv2

    colour = "a" if image_a.ndim == 3 else "b"
    cam = pid.cam_a if colour == "a" else pid.cam_b
    gray = lambda img: cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img  # noqa: E731
    note = (f"cameras {pid.cam_a},{pid.cam_b} mix gray and colour: image {colour} (camera {cam}) converted to gray; "
            "use --cams 0,1 or 2,3 for a pair of one kind")
    return gray(image_a), gray(image_b), note


_DRIVE = re.compile(r"^(\d{4}_\d{2}_\d{2})_(?:drive_)?(\d{4})(?:_sync)?$")


def _first_dir(candidates: list[Path]) -> Path | None:
    return next((c for c in candidates if c.is_dir()), None)


def open_odometry(root: Path, sequence: str) -> KittiSequence:
    seq = sequence.zfill(2) if sequence.isdigit() else sequence
    bases = [root / "odometry" / "dataset", root / "dataset", root]
    base = next((b for b in bases if (b / "sequences" / seq).is_dir()), None)
    if base is None:
        raise FvizError(f"--sequence {sequence}: no odometry layout under {root} (looked for [odometry/]dataset/sequences/{seq})")
    seq_dir = base / "sequences" / seq
    calib = seq_dir / "calib.txt"
    projections = _projections(calib, "P{cam}")
    return KittiSequence(
        source="odometry", name=seq, root=root, calib_path=calib, calib_key="P{cam}", projections=projections,
        image_dirs={cam: seq_dir / f"image_{cam}" for cam in projections},
        poses_path=base / "poses" / f"{seq}.txt",
    )


def open_raw(root: Path, drive: str) -> KittiSequence:
    m = _DRIVE.match(drive)
    if not m:
        raise FvizError(f"--drive {drive!r}: expected DATE_drive_NNNN (e.g. 2011_09_26_drive_0001)")
    date, number = m.groups()
    name = f"{date}_drive_{number}"
    date_dir = _first_dir([root / "raw" / date, root / date] + ([root] if root.name == date else []))
    if date_dir is None:
        raise FvizError(f"--drive {drive}: no raw layout under {root} (looked for [raw/]{date}/)")
    drive_dir = date_dir / f"{name}_sync"
    if not drive_dir.is_dir():
        raise FvizError(f"--drive {drive}: missing drive folder {drive_dir}")
    calib = date_dir / "calib_cam_to_cam.txt"
    projections = _projections(calib, "P_rect_0{cam}")
    return KittiSequence(
        source="raw", name=name, root=root, calib_path=calib, calib_key="P_rect_0{cam}", projections=projections,
        image_dirs={cam: drive_dir / f"image_0{cam}" / "data" for cam in projections}, oxts_dir=drive_dir / "oxts" / "data",
    )


def open_dataset(root: str | Path, sequence: str | None = None, drive: str | None = None) -> KittiSequence:
    """Open an odometry sequence (``sequence="00"``) or a raw drive (``drive="2011_09_26_drive_0001"``).

    With neither, the layout is auto-detected and must hold exactly one sequence or drive.
    """
    root = Path(root).expanduser()
    if not root.is_dir():
        raise FvizError(f"--kitti-root {root}: not a folder")
    if sequence and drive:
        raise FvizError("give --sequence (odometry) or --drive (raw), not both")
    if sequence:
        return open_odometry(root, sequence)
    if drive:
        return open_raw(root, drive)
    found = [("sequence", p.name) for b in (root / "odometry" / "dataset", root / "dataset", root)
             for p in sorted((b / "sequences").glob("*")) if p.is_dir()]
    found += [("drive", p.name[: -len("_sync")]) for b in (root / "raw", root) for p in sorted(b.glob("*/*_drive_*_sync"))]
    found += [("drive", p.name[: -len("_sync")]) for p in sorted(root.glob("*_drive_*_sync"))]
    if not found:
        raise FvizError(f"--kitti-root {root}: no KITTI layout found (expected odometry dataset/sequences/NN or raw "
                        "DATE/DATE_drive_NNNN_sync)")
    if len(found) > 1:
        listed = ", ".join(f"--{k} {v}" for k, v in found)
        raise FvizError(f"--kitti-root {root} holds several sequences/drives: pick one ({listed})")
    kind, name = found[0]
    return open_odometry(root, name) if kind == "sequence" else open_raw(root, name)
