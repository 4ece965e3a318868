"""A KITTI odometry sequence or raw drive (:class:`KittiSequence`): its frames, cameras and poses, and its pairs
with their ground truth; :func:`open_dataset` finds one under a root in either layout."""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from fviz.data.kitti.calib import decompose, rectified_projections
from fviz.data.kitti.files import lazy_image, read_image
from fviz.data.kitti.poses import OXTS_GT_ACCURACY_PX, oxts_camera_poses, read_poses
from fviz.data.pair import Pair, PairId
from fviz.errors import FvizError
from fviz.geometry import fundamental_from_projections

PAIR_KINDS = ("stereo", "temporal")
# How far the ground truth can be trusted (README of the sample data): calibration vs poses.
GT_ACCURACY_PX = {"stereo": 0.5, "temporal": 3.0}
# Without --cams: the gray cameras, or the colour ones where the gray images are absent (colour download).
DEFAULT_CAMS = {"stereo": ((0, 1), (2, 3)), "temporal": ((0, 0), (2, 2))}
MIN_BASELINE_M = 1e-6  # a pair moves by at least this much: without motion there is no F


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
        return read_poses(self.poses_path)

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
        _, t = decompose(self.projections[cam])
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
        K_a, _ = decompose(self.projections[pid.cam_a])
        K_b, _ = decompose(self.projections[pid.cam_b])
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
    projections = rectified_projections(calib, "P{cam}")
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
    projections = rectified_projections(calib, "P_rect_0{cam}")
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
