"""The KITTI data layer on the real samples: layouts, ground truth, and bad input."""

import shutil

import cv2
import numpy as np
import pytest

from fviz.data.kitti import open_dataset
from fviz.errors import FvizError
from fviz.estimators.classical import RobustConfig, magsac
from fviz.estimators.features import FeatureConfig, detect, match
from fviz.geometry import (
    NormalizationError,
    describe_epipole,
    epipoles,
    f_distance,
    fundamental_from_motion,
    normalize,
)
from fviz.geometry import symmetric_epipolar_distance as sed


def inlier_median_sed(pair):
    cfg = FeatureConfig(max_keypoints=4000)
    m = match(detect(pair.image_a, cfg), detect(pair.image_b, cfg), cfg)
    F, mask = magsac(m.x_a, m.x_b, RobustConfig(threshold=1.0))
    return float(np.median(sed(pair.F_gt, m.x_a[mask], m.x_b[mask]))), int(mask.sum())


@pytest.mark.parametrize("cams,frame", [((0, 1), 0), ((2, 3), 1), ((0, 2), 0)])
def test_odometry_stereo_ground_truth_under_half_a_pixel(odometry, cams, frame):
    med, n = inlier_median_sed(odometry.pair(frame, "stereo", cams=cams))
    assert n > 200 and med < 0.5


@pytest.mark.parametrize("cams,frame", [((0, 1), 0), ((2, 3), 5), ((0, 3), 9)])
def test_raw_stereo_ground_truth_under_half_a_pixel(raw_drive, cams, frame):
    med, n = inlier_median_sed(raw_drive.pair(frame, "stereo", cams=cams))
    assert n > 200 and med < 0.5


@pytest.mark.parametrize("frame,step", [(0, 1), (8, 1), (20, 3), (42, 1), (47, 2)])
def test_temporal_ground_truth_within_pose_accuracy(odometry, frame, step):
    pair = odometry.pair(frame, "temporal", step=step)
    med, n = inlier_median_sed(pair)
    assert n > 200 and med < pair.gt_accuracy_px == 3.0


def test_temporal_ground_truth_is_the_closed_form_of_the_relative_pose(odometry):
    pair = odometry.pair(10, "temporal", step=2)
    T = odometry.poses
    T_ab = np.linalg.inv(T[12]) @ T[10]  # camera 0 at frame 10 -> camera 0 at frame 12
    np.testing.assert_allclose(pair.R, T_ab[:3, :3], atol=1e-12)
    np.testing.assert_allclose(pair.t, T_ab[:3, 3], atol=1e-12)
    assert f_distance(pair.F_gt, fundamental_from_motion(pair.K_a, pair.K_b, pair.R, pair.t)) < 1e-9
    ep = describe_epipole(epipoles(pair.F_gt)[0], *pair.size_a)
    assert ep.inside  # the car drives forward: the focus of expansion is in the image
    assert 0.5 < np.linalg.norm(pair.t) < 3.0


def test_rectified_stereo_has_f33_zero_and_etr_says_so(odometry):
    pair = odometry.pair(0, "stereo")
    assert abs(normalize(pair.F_gt, "fbn")[2, 2]) < 1e-12
    assert np.linalg.norm(pair.t) == pytest.approx(0.537, abs=0.01)
    with pytest.raises(NormalizationError, match="F33"):
        normalize(pair.F_gt, "etr")


def test_pair_metadata(odometry, raw_drive):
    p = odometry.pair(3, "temporal", step=2)
    assert (p.id.frame_a, p.id.frame_b, p.id.cam_a, p.id.cam_b) == (3, 5, 0, 0)
    assert p.size_a == (1241, 376) and p.image_a.ndim == 2
    q = raw_drive.pair(0, "stereo", cams=(2, 3))
    assert q.size_a == (1242, 375) and q.image_a.shape == (375, 1242, 3)
    assert odometry.num_frames == 50 and raw_drive.num_frames == 10


def test_layout_auto_detection(kitti_root, tmp_path):
    # a root holding one sequence (or one drive) needs no --sequence / --drive
    one = tmp_path / "one" / "dataset" / "sequences"
    one.mkdir(parents=True)
    (one / "00").symlink_to(kitti_root / "odometry" / "dataset" / "sequences" / "00")
    assert open_dataset(tmp_path / "one").name == "00"
    drive = tmp_path / "raw" / "2011_09_26"
    drive.mkdir(parents=True)
    for f in (kitti_root / "raw" / "2011_09_26").iterdir():
        if f.name != "2011_09_26_drive_0002_sync":
            (drive / f.name).symlink_to(f)
    assert open_dataset(tmp_path / "raw").name == "2011_09_26_drive_0001"
    assert open_dataset(kitti_root, drive="2011_09_26_0001").source == "raw"
    # several: the error lists every one of them, so the user can pick
    sequences = sorted(p.name for p in (kitti_root / "odometry" / "dataset" / "sequences").iterdir() if p.is_dir())
    assert len(sequences) > 1
    with pytest.raises(FvizError, match="several") as err:
        open_dataset(kitti_root / "odometry")
    assert all(f"--sequence {s}" in str(err.value) for s in sequences)
    with pytest.raises(FvizError, match="several.*--drive 2011_09_26_drive_0001, --drive 2011_09_26_drive_0002"):
        open_dataset(kitti_root)
    with pytest.raises(FvizError, match="several.*--drive 2011_09_26_drive_0001, --drive 2011_09_26_drive_0002"):
        open_dataset(kitti_root / "raw")


def make_layout(tmp_path, kitti_root, frames=3, calib=True, poses=True):
    """A small odometry layout in tmp_path whose images link to the real samples."""
    src = kitti_root / "odometry" / "dataset"
    seq = tmp_path / "dataset" / "sequences" / "00"
    (seq / "image_0").mkdir(parents=True)
    for f in range(frames):
        (seq / "image_0" / f"{f:06d}.png").symlink_to(src / "sequences" / "00" / "image_0" / f"{f:06d}.png")
    if calib:
        shutil.copy(src / "sequences" / "00" / "calib.txt", seq / "calib.txt")
    if poses:
        (tmp_path / "dataset" / "poses").mkdir()
        shutil.copy(src / "poses" / "00.txt", tmp_path / "dataset" / "poses" / "00.txt")
    return seq


def test_bad_input_names_the_file_or_field(tmp_path, kitti_root):
    with pytest.raises(FvizError, match="no KITTI layout"):
        open_dataset(tmp_path)
    seq = make_layout(tmp_path, kitti_root, calib=False, poses=False)
    with pytest.raises(FvizError, match="calib.txt"):
        open_dataset(tmp_path, sequence="00")
    shutil.copy(kitti_root / "odometry/dataset/sequences/00/calib.txt", seq / "calib.txt")
    ds = open_dataset(tmp_path, sequence="00")
    with pytest.raises(FvizError, match=r"--frame 7 out of range.*0\.\.2 in image_0"):
        ds.pair(7, "temporal")
    with pytest.raises(FvizError, match="poses.*00.txt"):
        ds.pair(0, "temporal")
    with pytest.raises(FvizError, match="--cams: missing image folder .*image_1 \\(cameras with images here: 0\\)"):
        ds.pair(0, "stereo")
    with pytest.raises(FvizError, match="--cams 0,0"):
        ds.pair(0, "stereo", cams=(0, 0))
    with pytest.raises(FvizError, match="camera 7"):
        ds.pair(0, "stereo", cams=(0, 7))


def test_corrupt_and_mismatched_images(tmp_path, kitti_root):
    seq = make_layout(tmp_path, kitti_root)
    ds = open_dataset(tmp_path, sequence="00")
    (seq / "image_0" / "000001.png").unlink()
    (seq / "image_0" / "000001.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    with pytest.raises(FvizError, match="corrupt image.*000001.png"):
        ds.pair(0, "temporal")
    (seq / "image_0" / "000002.png").unlink()
    small = cv2.imread(str(kitti_root / "odometry/dataset/sequences/00/image_0/000002.png"))[:300, :1000]
    cv2.imwrite(str(seq / "image_0" / "000002.png"), small)
    with pytest.raises(FvizError, match="different sizes.*000002.png is 1000x300"):
        ds.pair(0, "temporal", step=2)


# ------------------------------------------------------------------ colour-only, gray-only and mixed layouts


def linked_layout(tmp_path, kitti_root, seq, cams):
    """A full-download-shaped odometry layout of one sequence: calib, poses and only the image folders of
    ``cams``, every file a symlink to the real sample."""
    src = kitti_root / "odometry" / "dataset"
    dst = tmp_path / "dataset" / "sequences" / seq
    for cam in cams:
        (dst / f"image_{cam}").mkdir(parents=True)
        for png in (src / "sequences" / seq / f"image_{cam}").glob("*.png"):
            (dst / f"image_{cam}" / png.name).symlink_to(png)
    (dst / "calib.txt").symlink_to(src / "sequences" / seq / "calib.txt")
    (tmp_path / "dataset" / "poses").mkdir()
    (tmp_path / "dataset" / "poses" / f"{seq}.txt").symlink_to(src / "poses" / f"{seq}.txt")
    return tmp_path


def n_images(kitti_root, seq, cam):
    return len(list((kitti_root / "odometry/dataset/sequences" / seq / f"image_{cam}").glob("*.png")))


@pytest.mark.parametrize("seq,kind,cams,step", [
    ("04", "stereo", None, 1),  # colour only: the default cameras are 2,3
    ("04", "temporal", None, 1),  # ... and 2,2
    ("04", "temporal", (2, 3), 1),  # cross-camera: left at t, right at t+1
    ("02", "temporal", (2, 2), 2),  # colour left only
    ("10", "temporal", None, 1),
])
def test_colour_only_sequences_work_with_their_own_frame_counts(kitti_root, tmp_path, seq, kind, cams, step):
    assert n_images(kitti_root, seq, 0) == 0  # no gray images: the old count gave "frames 0..-1"
    n = n_images(kitti_root, seq, 2)
    for root in (kitti_root, linked_layout(tmp_path, kitti_root, seq, (2, 3) if seq == "04" else (2,))):
        ds = open_dataset(root, sequence=seq)
        last = n - 1 - (step if kind == "temporal" else 0)
        pair = ds.pair(last, kind, step=step, cams=cams)
        assert (pair.id.cam_a, pair.id.cam_b) == (cams or ((2, 3) if kind == "stereo" else (2, 2)))
        assert pair.image_a.ndim == 3 and pair.notes == []
        med, inliers = inlier_median_sed(pair)
        assert inliers > 100 and med < pair.gt_accuracy_px
        with pytest.raises(FvizError, match=rf"--frame \+ --step {n} out of range.*frames 0\.\.{n - 1} in image_2"):
            ds.pair(n - 1, "temporal", cams=(2, 2))


def test_gray_only_layout(kitti_root, tmp_path):
    root = linked_layout(tmp_path, kitti_root, "03", (0, 1))
    ds = open_dataset(root, sequence="03")
    n = n_images(kitti_root, "03", 0)
    assert ds.frames_of((0, 1)) == n and ds.default_cams("stereo") == (0, 1)
    for kind, cams in (("stereo", (0, 1)), ("temporal", (0, 0)), ("temporal", (1, 1)), ("temporal", (0, 1))):
        pair = ds.pair(n - 2, kind, cams=cams)
        assert pair.image_a.ndim == 2 and pair.image_b.ndim == 2
        med, inliers = inlier_median_sed(pair)
        assert inliers > 100 and med < pair.gt_accuracy_px, (kind, cams)
    with pytest.raises(FvizError, match=r"--cams: missing image folder .*03/image_2 \(cameras with images here: 0, 1\)"):
        ds.pair(0, "stereo", cams=(2, 3))


def test_mixed_gray_colour_pair_is_evaluated_in_gray_and_says_so(odometry):
    pair = odometry.pair(1, "stereo", cams=(0, 2))
    colour = cv2.imread(str(odometry.image_path(2, 1)))
    assert colour.ndim == 3
    np.testing.assert_array_equal(pair.image_b, cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY))
    assert pair.image_a.ndim == 2
    assert pair.notes == ["cameras 0,2 mix gray and colour: image b (camera 2) converted to gray; "
                          "use --cams 0,1 or 2,3 for a pair of one kind"]
    med, inliers = inlier_median_sed(pair)
    assert inliers > 200 and med < 0.5


def test_a_pair_decodes_its_images_only_when_read(odometry, kitti_root):
    """A KITTI pair knows its image sizes from the PNG headers; the pixels are decoded on the first read (the
    same as OpenCV's), and not at all where the features of both frames are at hand (a run's other pairs)."""
    from fviz.data.pair import LazyImage
    from fviz.estimators import get_estimator
    from fviz.estimators.features import FeatureCache
    from fviz.evaluate import evaluate_pair

    pair = odometry.pair(5, "temporal")
    assert isinstance(pair.__dict__["image_a"], LazyImage) and pair.size_a == pair.size_b == (1241, 376)
    path = kitti_root / "odometry/dataset/sequences/00/image_0/000005.png"
    np.testing.assert_array_equal(pair.image_a, cv2.imread(str(path), cv2.IMREAD_UNCHANGED))
    assert not isinstance(pair.__dict__["image_a"], LazyImage) and isinstance(pair.__dict__["image_b"], LazyImage)

    fresh, cache = odometry.pair(5, "temporal"), FeatureCache(FeatureConfig())
    cache.put({pair.id.key_a: detect(pair.image_a), pair.id.key_b: detect(pair.image_b)})
    result = evaluate_pair(fresh, [("magsac", get_estimator("magsac"))], cache=cache)
    assert result.n_matches > 100 and cache.misses == 0
    assert all(isinstance(fresh.__dict__[k], LazyImage) for k in ("image_a", "image_b"))
