"""Raw-drive temporal ground truth from the oxts GPS/IMU packets (drive 0002 of the samples: frames 0-9):
the pose chain against a closed form written here, the F against the images, bad packets, the CLI, training."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from cli_util import assert_one_line_error, run_fviz
from fviz.data.kitti import GT_ACCURACY_PX, OXTS_GT_ACCURACY_PX, open_dataset
from fviz.errors import FvizError
from fviz.geometry import f_distance

DRIVE = "2011_09_26_drive_0002"


@pytest.fixture(scope="module")
def drive(kitti_root):
    return open_dataset(kitti_root, drive=DRIVE)


def _numbers(path: Path, key: str) -> list[float]:
    line = next(x for x in path.read_text().splitlines() if x.startswith(key + ":"))
    return [float(v) for v in line.split(":", 1)[1].split()]


def _rigid(R: list[float], t: list[float]) -> np.ndarray:
    return np.block([[np.array(R).reshape(3, 3), np.array(t).reshape(3, 1)], [np.zeros((1, 3)), np.ones((1, 1))]])


def _inverse(T: np.ndarray) -> np.ndarray:
    """Closed-form inverse of [A | t]: [A^-1 | -A^-1 t], A^-1 by the adjugate (rows' cross products over the
    determinant; KITTI's calibration rotations are printed to 1e-6, so A^T is not quite A^-1)."""
    r0, r1, r2 = T[:3, :3]
    A_inv = np.column_stack([np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)]) / np.dot(r0, np.cross(r1, r2))
    return _rigid(A_inv.ravel().tolist(), (-A_inv @ T[:3, 3]).tolist())


def _imu_to_world(lat0: float, packet: list[float]) -> np.ndarray:
    """T_w_imu written differently from fviz: the Z-Y-X Euler matrix spelt out element by element, and the
    Mercator northing as er * asinh(tan(lat)) (= er * ln tan(45 deg + lat / 2))."""
    lat, lon, alt, roll, pitch, yaw = packet[:6]
    s = math.cos(math.radians(lat0))
    er = 6378137.0
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    R = [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr,
         sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr,
         -sp, cp * sr, cp * cr]
    return _rigid(R, [s * er * math.radians(lon), s * er * math.asinh(math.tan(math.radians(lat))), alt])


def _closed_form_camera_poses(date_dir: Path, drive_dir: Path, frames: range) -> list[np.ndarray]:
    """Rectified camera 0 -> world (camera 0 at frame 0) from the raw text files."""
    packets = [[float(v) for v in (drive_dir / "oxts" / "data" / f"{f:010d}.txt").read_text().split()] for f in frames]
    imu_velo = _rigid(_numbers(date_dir / "calib_imu_to_velo.txt", "R"), _numbers(date_dir / "calib_imu_to_velo.txt", "T"))
    velo_cam = _rigid(_numbers(date_dir / "calib_velo_to_cam.txt", "R"), _numbers(date_dir / "calib_velo_to_cam.txt", "T"))
    rect = _rigid(_numbers(date_dir / "calib_cam_to_cam.txt", "R_rect_00"), [0.0, 0.0, 0.0])
    imu_from_cam = _inverse(rect @ velo_cam @ imu_velo)
    world_from_cam = [_imu_to_world(packets[0][0], p) @ imu_from_cam for p in packets]
    return [_inverse(world_from_cam[0]) @ T for T in world_from_cam]


def test_oxts_poses_are_the_closed_form_chain(kitti_root, drive):
    date_dir = kitti_root / "raw" / "2011_09_26"
    expected = _closed_form_camera_poses(date_dir, date_dir / f"{DRIVE}_sync", range(10))
    # Rotations to 1e-9; positions to 1e-8 m: Mercator northings of ~5.4e6 m round at ~1e-9 m before differencing.
    np.testing.assert_allclose(drive.poses[:10, :3, :3], np.stack(expected)[:, :3, :3], atol=1e-9)
    np.testing.assert_allclose(drive.poses[:10, :3, 3], np.stack(expected)[:, :3, 3], atol=1e-8)
    np.testing.assert_allclose(drive.poses[0], np.eye(4), atol=1e-12)
    K = np.array(_numbers(date_dir / "calib_cam_to_cam.txt", "P_rect_00")).reshape(3, 4)[:, :3]
    for a, b in [(0, 1), (3, 4), (2, 7)]:
        pair = drive.pair(a, "temporal", step=b - a)
        T_ab = _inverse(expected[b]) @ expected[a]  # camera 0 at frame a -> camera 0 at frame b
        np.testing.assert_allclose(pair.R, T_ab[:3, :3], atol=1e-9)
        np.testing.assert_allclose(pair.t, T_ab[:3, 3], atol=1e-8)
        tx = np.array([[0, -T_ab[2, 3], T_ab[1, 3]], [T_ab[2, 3], 0, -T_ab[0, 3]], [-T_ab[1, 3], T_ab[0, 3], 0]])
        Kinv = np.linalg.inv(K)
        assert f_distance(pair.F_gt, Kinv.T @ tx @ T_ab[:3, :3] @ Kinv) < 1e-9
        assert pair.gt_accuracy_px == OXTS_GT_ACCURACY_PX > GT_ACCURACY_PX["temporal"]
        # The car drives forward about 9 m/s at 10 Hz: camera 0's z (forward) carries the motion.
        assert 0.7 * (b - a) < -pair.t[2] < 1.1 * (b - a)


def _magsac_inlier_sed(pair) -> tuple[float, int]:
    """Median symmetric epipolar distance (px, the mean of the two point-line distances) of OpenCV SIFT +
    MAGSAC++ inliers to the pair's F_gt."""
    sift = cv2.SIFT_create(4000)
    ka, da = sift.detectAndCompute(pair.image_a, None)
    kb, db = sift.detectAndCompute(pair.image_b, None)
    good = [m for m, n in cv2.BFMatcher().knnMatch(da, db, k=2) if m.distance < 0.8 * n.distance]
    xa = np.float64([ka[m.queryIdx].pt for m in good])
    xb = np.float64([kb[m.trainIdx].pt for m in good])
    _, mask = cv2.findFundamentalMat(xa, xb, cv2.USAC_MAGSAC, 1.0, 0.999, 10000)
    inl = mask.ravel().astype(bool)
    ha, hb = np.c_[xa[inl], np.ones(inl.sum())], np.c_[xb[inl], np.ones(inl.sum())]
    lines_b, lines_a = ha @ pair.F_gt.T, hb @ pair.F_gt  # rows F x_a (in image b) and F^T x_b (in image a)
    r = np.abs(np.sum(hb * lines_b, axis=1))
    d = 0.5 * (r / np.hypot(lines_b[:, 0], lines_b[:, 1]) + r / np.hypot(lines_a[:, 0], lines_a[:, 1]))
    return float(np.median(d)), int(inl.sum())


@pytest.mark.parametrize("frame,cams", [(0, (0, 0)), (2, (0, 0)), (3, (0, 0)), (6, (0, 0)), (8, (0, 0)), (4, (2, 2))])
def test_oxts_f_agrees_with_the_images_on_adjacent_frames(drive, frame, cams):
    med, n = _magsac_inlier_sed(drive.pair(frame, "temporal", cams=cams))
    assert n > 500 and med < 1.0, (med, n)


@pytest.fixture
def drive_copy(kitti_root, tmp_path):
    """The drive's layout in tmp: calibration files, image folder and oxts packets as links, so a test can drop
    or replace one packet."""
    src = kitti_root / "raw" / "2011_09_26"
    date = tmp_path / "raw" / "2011_09_26"
    (date / f"{DRIVE}_sync" / "oxts" / "data").mkdir(parents=True)
    for name in ("calib_cam_to_cam.txt", "calib_imu_to_velo.txt", "calib_velo_to_cam.txt"):
        (date / name).symlink_to(src / name)
    (date / f"{DRIVE}_sync" / "image_00").symlink_to(src / f"{DRIVE}_sync" / "image_00")
    for p in (src / f"{DRIVE}_sync" / "oxts" / "data").glob("*.txt"):
        (date / f"{DRIVE}_sync" / "oxts" / "data" / p.name).symlink_to(p)
    return tmp_path, date / f"{DRIVE}_sync" / "oxts" / "data"


def test_a_missing_packet_fails_only_the_pairs_that_need_it(drive_copy):
    root, oxts = drive_copy
    (oxts / "0000000005.txt").unlink()
    ds = open_dataset(root, drive=DRIVE)
    for frame in (4, 5):
        with pytest.raises(FvizError) as exc:
            ds.pair(frame, "temporal")
        assert str(exc.value) == f"missing oxts packet of frame 5: {oxts / '0000000005.txt'}"
    assert ds.pair(6, "temporal").gt_accuracy_px == OXTS_GT_ACCURACY_PX
    assert ds.pose_frames == set(range(10)) - {5}


def test_without_an_oxts_folder_temporal_pairs_name_it(drive_copy):
    root, oxts = drive_copy
    for p in oxts.iterdir():
        p.unlink()
    oxts.rmdir()
    ds = open_dataset(root, drive=DRIVE)
    assert ds.pose_frames == set()
    with pytest.raises(FvizError, match=f"temporal pairs need ground-truth poses: missing oxts folder {oxts}"):
        ds.pair(0, "temporal")


def _replace_packet(oxts: Path, frame: int, edit) -> Path:
    path = oxts / f"{frame:010d}.txt"
    values = path.read_text().split()
    path.unlink()
    path.write_text(" ".join(edit(values)) + "\n")
    return path


@pytest.mark.parametrize("edit,message", [
    (lambda v: v[:-1], "0000000005.txt:1: 29 numbers, expected 30"),
    (lambda v: ["nan", *v[1:]], "0000000005.txt:1: NaN or infinite numbers"),
    (lambda v: [v[0], "4x2", *v[2:]], "0000000005.txt:1: cannot parse the numbers"),
])
def test_a_corrupt_packet_is_a_one_line_error_naming_file_and_line(drive_copy, tmp_path, edit, message):
    root, oxts = drive_copy
    path = _replace_packet(oxts, 5, edit)
    proc = run_fviz("inspect", "pair", "--kitti-root", root, "--drive", DRIVE, "--pair", "temporal", "--frame", "2",
                    "-e", "8point", "--out", tmp_path / "x.rrd")
    assert_one_line_error(proc, 2, f"oxts packet {path}", message)
    assert not (tmp_path / "x.rrd").exists()


def test_cli_inspect_a_raw_temporal_pair(kitti_root, drive, tmp_path):
    from fviz.record.reader import image_size
    from fviz.record.rebuild import match_classes

    out = tmp_path / "x.rrd"
    proc = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--drive", DRIVE, "--pair", "temporal", "--frame", "3",
                    "-e", "magsac", "--out", out, "--json")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert doc["pair"]["kind"] == "temporal" and (doc["pair"]["frame_a"], doc["pair"]["frame_b"]) == (3, 4)
    assert doc["pair"]["gt_accuracy_px"] == OXTS_GT_ACCURACY_PX > GT_ACCURACY_PX["temporal"]
    assert f_distance(np.array(doc["F_gt"]), drive.pair(3, "temporal").F_gt) < 1e-9
    gt, magsac = doc["estimators"][0], doc["estimators"][1]
    assert gt["name"] == "gt" and magsac["error"] is None and magsac["metrics"]["sed_median"] < 1.0
    assert out.is_file() and image_size(out, "a") == (1242, 375) and set(match_classes(out)) == {"gt", "magsac"}


def test_training_selects_raw_temporal_pairs_with_packets(kitti_root, tmp_path):
    from fviz.train.data import KittiPairs
    from fviz.train.splits import kitti_items
    from fviz.train.recipe import Recipe

    def items(drive_name):
        recipe = Recipe.from_dict({
            "model": {"variant": "siamese-rec-pos-fbn", "input_size": [32, 96], "width": 8, "hidden": 16, "pool_grid": [2, 4]},
            "data": {"source": "kitti-odometry", "root": str(kitti_root), "drives": [drive_name], "kinds": ["temporal"],
                     "cameras": [0], "steps": [1, 2]},
            "train": {"out_dir": str(tmp_path / "run")},
        })
        return kitti_items(recipe, drive_name)

    got = items(DRIVE)
    assert sorted((i.frame, i.step) for i in got) == [(f, s) for f in range(9) for s in (1, 2) if f + s <= 9]
    _, _, F = KittiPairs(got, (32, 96), "fbn")[[0]]
    assert np.isfinite(F.numpy()).all()
    with pytest.raises(FvizError, match="gives no temporal pairs"):  # drive 0001: a packet for frame 0 only
        items("2011_09_26_drive_0001")


def test_cli_eval_records_a_missing_packet_per_pair_and_goes_on(drive_copy, tmp_path):
    from cli_util import read_csv

    root, oxts = drive_copy
    missing = oxts / "0000000002.txt"
    missing.unlink()
    out = tmp_path / "run"
    proc = run_fviz("eval", "--kitti-root", root, "--drive", DRIVE, "--pair", "temporal", "--frames", "0:5", "-e", "magsac",
                    "--out-dir", out, "--workers", "1", timeout=300)
    assert proc.returncode == 0, proc.stderr
    rows = {(int(r["frame_a"]), r["estimator"]): r for r in read_csv(out / "metrics.csv")}
    for frame in (1, 2):  # 1 -> 2 and 2 -> 3 need the missing packet
        assert rows[(frame, "magsac")]["pair_error"] == f"missing oxts packet of frame 2: {missing}"
    for frame in (0, 3):
        r = rows[(frame, "magsac")]
        assert not r["pair_error"] and float(r["gt_accuracy_px"]) == OXTS_GT_ACCURACY_PX and float(r["sed_median"]) < 1.0
