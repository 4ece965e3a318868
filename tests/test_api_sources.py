"""One typed constructor per source (issue 41, item 3): each gives the pair ``fviz.load_pair`` gives for the same
source (the same pixels and ground truth), takes paths, numbers and tuples rather than flag strings, and names its own
parameter in a one-line error."""

from __future__ import annotations

import numpy as np
import pytest

import fviz
from fviz.errors import FvizError


def _same(p, q) -> None:
    assert p.id.name == q.id.name
    assert np.array_equal(p.image_a, q.image_a) and np.array_equal(p.image_b, q.image_b)
    assert (p.F_gt is None) == (q.F_gt is None) and (p.F_gt is None or np.allclose(p.F_gt, q.F_gt))


@pytest.mark.kitti
def test_kitti_pair(kitti_root):
    _same(fviz.kitti_pair(kitti_root, sequence="00", frame=3, kind="temporal", step=2),
          fviz.load_pair(kitti_root, sequence="00", frame=3, kind="temporal", step=2))
    p = fviz.kitti_pair(kitti_root, sequence="00", frame=0, cams=(0, 1))
    assert p.id.cam_a == 0 and p.id.cam_b == 1 and abs(p.F_gt[2, 2]) < 1e-9  # rectified stereo: F33 = 0


def test_synthetic_pair():
    _same(fviz.synthetic_pair(4, kind="temporal"), fviz.load_pair(synthetic=True, seed=4, kind="temporal"))


@pytest.mark.kitti
def test_pairs_file_and_colmap_pairs(strecha_root):
    root = strecha_root / "fountain-P11"
    p = fviz.pairs_file_pair(root / "pairs_with_gt.txt", root / "images", index=1)
    _same(p, fviz.load_pair(pairs=root / "pairs_with_gt.txt", images=root / "images", index=1))
    assert p.id.image_a == "0000.jpg" and p.id.image_b == "0002.jpg"
    _same(fviz.pairs_file_pair(root / "pairs_with_gt.txt", root / "images", names=("0000.jpg", "0002.jpg")), p)
    c = fviz.colmap_pair(root / "colmap", root / "images", names=("0000.jpg", "0001.jpg"))
    _same(c, fviz.load_pair(colmap=root / "colmap", images=root / "images", image_a="0000.jpg", image_b="0001.jpg"))


def test_with_matches(tmp_path):
    p = fviz.synthetic_pair(1, kind="temporal")
    r = fviz.inspect_pair(p, ("8point",))
    rows = np.hstack([r.matches.x_a[:40], r.matches.x_b[:40]])
    np.savetxt(tmp_path / "m.txt", rows)
    q = fviz.with_matches(fviz.synthetic_pair(1, kind="temporal"), tmp_path / "m.txt")
    assert np.allclose(q.matches.x_a, rows[:, :2]) and np.allclose(q.matches.x_b, rows[:, 2:])


@pytest.mark.parametrize("call, words", [
    (lambda: fviz.synthetic_pair(-1), "seed: expected an int >= 0"),
    (lambda: fviz.synthetic_pair(0, kind="sideways"), "kind 'sideways': 'stereo' or 'temporal'"),
    (lambda: fviz.kitti_pair("/nonexistent-kitti", sequence="00", frame=1.5), "frame: expected an int >= 0"),
    (lambda: fviz.kitti_pair("/nonexistent-kitti", sequence="00", cams=(0,)), "cams: expected two camera numbers"),
    (lambda: fviz.kitti_pair(3, sequence="00"), "kitti_root: expected a path"),
    (lambda: fviz.pairs_file_pair("p.txt", "images"), "index: give the pair by index"),
    (lambda: fviz.pairs_file_pair("p.txt", "images", index=0, names=("a", "b")), "index: give the pair by index"),
    (lambda: fviz.with_matches("not a pair", "m.txt"), "pair: expected an fviz.Pair"),
    (lambda: fviz.with_matches(fviz.synthetic_pair(0)), "matches: give a matches file"),
])
def test_errors_name_the_parameter(call, words):
    with pytest.raises(FvizError) as e:
        call()
    assert str(e.value).startswith(words) and "\n" not in str(e.value) and "--" not in str(e.value)


def test_load_pair_errors_name_parameters_from_python():
    with pytest.raises(FvizError) as e:
        fviz.load_pair(matches="/nonexistent/m.h5", synthetic=True)
    assert str(e.value).startswith("matches /nonexistent/m.h5: no such file")
