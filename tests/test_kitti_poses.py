"""Ground truth from bad poses is refused: a 6-frame copy of sample sequence 00 whose poses file
is damaged, through the real ``fviz`` in a subprocess."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from cli_util import assert_one_line_error, read_csv, run_fviz



pytestmark = pytest.mark.kitti
FAST = ("--max-keypoints", "300", "--workers", "1", "--no-progress")


@pytest.fixture
def six_frames(kitti_root, tmp_path):
    """(root, poses (6, 12)) of a copy of sequence 00 with frames 0-5 of camera 0 (images linked, not copied)."""
    src = kitti_root / "odometry" / "dataset"
    seq = tmp_path / "kitti" / "odometry" / "dataset" / "sequences" / "00"
    (seq / "image_0").mkdir(parents=True)
    shutil.copy(src / "sequences" / "00" / "calib.txt", seq / "calib.txt")
    for f in range(6):
        (seq / "image_0" / f"{f:06d}.png").symlink_to(src / "sequences" / "00" / "image_0" / f"{f:06d}.png")
    (tmp_path / "kitti" / "odometry" / "dataset" / "poses").mkdir()
    poses = np.loadtxt(src / "poses" / "00.txt")[:6]
    return tmp_path / "kitti", poses


def write_poses(root, poses):
    np.savetxt(root / "odometry" / "dataset" / "poses" / "00.txt", poses, fmt="%.9e")


def inspect(root, frame=0, *extra):
    return run_fviz("inspect", "pair", "--kitti-root", root, "--sequence", "00", "--pair", "temporal",
                    "--frame", frame, "-e", "8point", "--max-keypoints", "300", "--out", root / "x.rrd", *extra)


def test_equal_poses_are_a_pair_without_f_not_a_linalg_traceback(six_frames):
    root, poses = six_frames
    write_poses(root, np.tile(poses[0], (6, 1)))
    assert_one_line_error(inspect(root), 2, "00.txt", "frames 0 and 1", "no fundamental matrix")
    # oracle-mean over pairs of which none has an F: one line, not a traceback
    r = run_fviz("eval", "--kitti-root", root, "--sequence", "00", "--pair", "temporal", "--frames", "0:3",
                 "-e", "8point", "-e", "oracle-mean", *FAST, "--out-dir", root / "run")
    assert_one_line_error(r, 2, "oracle-mean", "no fundamental matrix")


def test_a_standing_pair_fails_alone_and_oracle_mean_is_the_mean_of_the_others(six_frames):
    root, poses = six_frames
    poses[2] = poses[1]  # frames 1 and 2 at the same place
    write_poses(root, poses)
    out = root / "run"
    r = run_fviz("eval", "--kitti-root", root, "--sequence", "00", "--pair", "temporal", "--frames", "0:4",
                 "-e", "8point", "-e", "oracle-mean", *FAST, "--out-dir", out, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "1 pairs without a ground-truth F left out of the mean" in r.stderr
    by_pair = {}
    for row in read_csv(out / "metrics.csv"):
        by_pair.setdefault(int(row["frame_a"]), set()).add(row["pair_error"])
    assert by_pair[1] != {""} and all("no fundamental matrix" in e for e in by_pair[1])
    assert by_pair[0] == by_pair[2] == {""}
    # the baseline's F is the mean of the two pairs with motion (independent computation from the poses)
    from fviz.data.kitti import open_dataset
    from fviz.estimators.baselines import mean_fundamental

    ds = open_dataset(root, "00")
    expected = mean_fundamental(ds.ground_truth(ds.pair_id(f, "temporal"))[4] for f in (0, 2))
    got = np.array(json.loads((out / "run.json").read_text())["baseline_F"]["oracle-mean"]).reshape(3, 3)
    np.testing.assert_allclose(got, expected, atol=1e-12)


def test_a_huge_translation_is_refused_naming_its_line(six_frames):
    root, poses = six_frames
    poses[3, 3] = 1e300
    write_poses(root, poses)
    assert_one_line_error(inspect(root), 2, "00.txt:4", "translation")


def test_a_rotation_block_that_is_not_a_rotation_is_refused(six_frames):
    root, poses = six_frames
    R = poses[1].reshape(3, 4)[:, :3] @ np.array([[1, 0.05, 0], [0, 1, 0], [0, 0, 1]])  # a shear
    poses[1].reshape(3, 4)[:, :3] = R
    write_poses(root, poses)
    assert_one_line_error(inspect(root), 2, "00.txt:2", "not a rotation")


def test_the_real_poses_pass_the_checks(kitti_root):
    from fviz.data.kitti import ROTATION_TOL, open_dataset

    T = open_dataset(kitti_root, "00").poses  # checked on reading
    R = T[:, :3, :3]
    err = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max()
    assert err < ROTATION_TOL / 10  # the tolerance is far from what real poses need
