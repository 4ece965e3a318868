"""Ignored or contradictory inputs get a note or a one-line error, never silence: KITTI flags beside a
user's images, a COLMAP model without 3D points and --min-shared, K whose principal point lies outside its image, the
same image twice, --pairs without --images, `fviz inspect --kitti-root` (no `pair`), kusvod2's ``{name}_pts.txt``."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest
from cli_util import assert_one_line_error, run_fviz

from fviz.errors import FvizError

pytestmark = pytest.mark.kitti


@pytest.fixture(scope="module")
def frames(kitti_root):
    seq = kitti_root / "odometry" / "dataset" / "sequences" / "00" / "image_0"
    return seq / "000000.png", seq / "000001.png"


@pytest.mark.parametrize("command", ["inspect", "eval"])
def test_kitti_flags_with_two_images_are_refused(kitti_root, frames, tmp_path, command):
    a, b = frames
    args = (["inspect", "pair", "--out", tmp_path / "x.rrd"] if command == "inspect"
            else ["eval", "--out-dir", tmp_path / "run", "--no-progress"])
    r = run_fviz(*args, "--kitti-root", kitti_root, "--sequence", "00", "--image-a", a, "--image-b", b)
    assert_one_line_error(r, 2, "--kitti-root: not with --image-a/--image-b", "give one source")
    r = run_fviz(*args, "--sequence", "00", "--image-a", a, "--image-b", b)
    assert_one_line_error(r, 2, "--sequence: not with --image-a/--image-b")


def test_inspect_without_pair_suggests_it(kitti_root):
    r = run_fviz("inspect", "--kitti-root", kitti_root, "--sequence", "00", "--frame", "3")
    assert_one_line_error(r, 2, "fviz inspect: no such option --kitti-root: did you mean "
                                f"`fviz inspect pair --kitti-root {kitti_root} --sequence 00 --frame 3`?")


def test_the_same_image_twice_is_refused_and_identical_pixels_noted(frames, tmp_path):
    from fviz.data.images import two_images

    a, _ = frames
    r = run_fviz("inspect", "pair", "--image-a", a, "--image-b", a, "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, "--image-a/--image-b: image a and image b are the same file")
    copy = tmp_path / "copy.png"
    shutil.copy(a, copy)
    pair = two_images(str(a), str(copy))
    assert any("identical pixels" in n for n in pair.notes), pair.notes


def test_a_principal_point_outside_the_image_is_refused(frames, tmp_path):
    """KITTI's 1241x376 frames with K of an image three times that size: the error names --K."""
    a, b = frames
    r = run_fviz("inspect", "pair", "--image-a", a, "--image-b", b, "--K", "2154,2154,1821,555", "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, "--K: principal point (1821.0, 555.0) lies outside the 1241x376 image a",
                          "a resized image with the full-size K")
    r = run_fviz("inspect", "pair", "--image-a", a, "--image-b", b, "--K-a", "718,718,607,185", "--K-b", "718,718,607,500",
                 "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, "--K-b: principal point (607.0, 500.0) lies outside the 1241x376 image b")


def test_a_resized_strecha_pair_with_the_full_size_k_is_refused(strecha_root, tmp_path):
    """Fountain 0 -> 1 at a quarter of its size, its pairs-file line keeping the published (full-size) K."""
    from fviz.data.pairsfile import PairsSource

    src = strecha_root / "fountain-P11"
    line = (src / "pairs_with_gt.txt").read_text().splitlines()[0]
    for name in line.split()[:2]:
        im = cv2.imread(str(src / "images" / name))
        cv2.imwrite(str(tmp_path / name), cv2.resize(im, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA))
    (tmp_path / "pairs.txt").write_text(line + "\n")
    source = PairsSource(tmp_path / "pairs.txt", tmp_path)
    with pytest.raises(FvizError, match=r"pairs.txt:1: K0: principal point \(1520.7, 1006.8\) lies outside the 768x512 "
                                        r"image a"):
        source.load(source.pair_ids()[0])


def test_pairs_without_images_suggest_images(frames, tmp_path):
    pairs = tmp_path / "lists" / "pairs.txt"
    pairs.parent.mkdir()
    pairs.write_text(f"{frames[0].name} {frames[1].name}\n")
    r = run_fviz("inspect", "pair", "--pairs", pairs, "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, f"image a {pairs.parent / frames[0].name}: no such file",
                          f"the names in --pairs {pairs} are relative to --images DIR", "give --images")
    r = run_fviz("inspect", "pair", "--pairs", pairs, "--images", tmp_path, "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, "no such file")
    assert "--images DIR" not in r.stderr  # given: nothing to suggest


def test_a_colmap_model_without_3d_points_notes_that_min_shared_does_not_apply(strecha_root, capsys):
    from fviz.data.colmap import ColmapSource

    model = strecha_root / "fountain-P11" / "colmap"
    source = ColmapSource(model, strecha_root / "fountain-P11" / "images", None, 50)
    assert len(source.pair_ids()) == 55  # every pair of the 11 images
    err = capsys.readouterr().err
    assert f"note: --colmap {model} has no 3D points (points3D is empty): all 55 pairs of its 11 images are taken " \
           "and --min-shared 50 does not apply" in err


def test_kusvod2_pts_files_are_found_in_folder_mode(frames, tmp_path):
    """Images BrusselsA / BrusselsB and their ground-truth correspondences Brussels_pts.txt (AdelaideRMF rows)."""
    from fviz.data.match_files import open_gt_matches
    from fviz.data.images import two_images

    images, gt = tmp_path / "images", tmp_path / "gt"
    images.mkdir(), gt.mkdir()
    for src, name in zip(frames, ("BrusselsA.png", "BrusselsB.png")):
        (images / name).symlink_to(src)
    pair = two_images(str(images / "BrusselsA.png"), str(images / "BrusselsB.png"))
    rng = np.random.default_rng(0)
    pts = rng.uniform([10, 10], [1200, 360], (20, 2))
    rows = np.c_[pts, np.ones(20), pts + [5, 0], np.ones(20), np.r_[np.ones(15), np.zeros(5)]]
    with pytest.raises(FvizError, match=r"--gt-matches .*: no BrusselsA_BrusselsB.txt for the pair .* \(nor "
                                        r"BrusselsB_BrusselsA.txt, Brussels_pts.txt, Brussels.txt\)"):
        open_gt_matches(gt).for_pair(pair)
    np.savetxt(gt / "Brussels_pts.txt", rows)
    c = open_gt_matches(gt).for_pair(pair)
    assert len(c.x_a) == 15 and c.path.endswith("Brussels_pts.txt")
