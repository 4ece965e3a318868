"""Training data from real KITTI: pair selection across sequences, cameras and directions, augmentations
that keep F exact (closed form on exact correspondences, and image matches on real pairs), the GT filter."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fviz.errors import FvizError
from fviz.geometry import f_distance, symmetric_epipolar_distance
from fviz.models.predict import flip_matrix
from fviz.train.augment import Augment, augmented_pair
from fviz.train.data import KittiItem, KittiPairs, load_kitti_pair
from fviz.train.splits import filter_by_gt_agreement, gt_agreement_px, kitti_items, make_datasets
from fviz.train.recipe import Recipe

EVERYTHING = Augment(swap=0.5, flip=0.5, crop=0.3, photometric=1.0)


def _recipe(root, tmp_path, **data) -> Recipe:
    return Recipe.from_dict({
        "model": {"variant": "siamese-rec-pos-fbn", "input_size": [32, 96], "width": 8, "hidden": 16, "pool_grid": [2, 4]},
        "data": {"source": "kitti-odometry", "root": str(root), **data},
        "train": {"out_dir": str(tmp_path / "run")},
    })


def _maps_apply(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    xh = np.c_[x, np.ones(len(x))] @ A.T
    return xh[:, :2] / xh[:, 2:]


def test_flip_matrix_mirrors_pixel_centres():
    img = np.arange(5 * 7, dtype=np.uint8).reshape(5, 7)
    A = flip_matrix(7)
    for x in range(7):
        x2 = _maps_apply(A, np.array([[x, 2.0]]))[0, 0]
        assert img[2, ::-1][int(x2)] == img[2, x]


@pytest.mark.parametrize("seed", range(6))
def test_augmentations_keep_f_exact_on_exact_correspondences(seed):
    """Synthetic scenes know their exact correspondences: mapped by the augmentation's pixel maps they
    satisfy the augmented F to 1e-6 px, and OpenCV's 8-point on them recovers the same F."""
    from fviz.data.synthetic import SceneConfig, synthetic_pair

    pair = synthetic_pair(100 + seed, SceneConfig(stereo=bool(seed % 2), n_points=400))
    rng = np.random.default_rng(seed)
    a, b, F, (A_a, A_b, swapped) = augmented_pair(pair.image_a, pair.image_b, pair.F_gt, (120, 400), EVERYTHING, rng, return_maps=True)
    x_a, x_b = (pair.points_b, pair.points_a) if swapped else (pair.points_a, pair.points_b)
    y_a, y_b = _maps_apply(A_a, x_a), _maps_apply(A_b, x_b)
    assert a.shape == b.shape == (120, 400)
    assert np.max(symmetric_epipolar_distance(F, y_a, y_b)) < 1e-6
    F8, _ = cv2.findFundamentalMat(y_a, y_b, cv2.FM_8POINT)
    assert f_distance(F8, F) < 1e-4


def _matched_sed(a: np.ndarray, b: np.ndarray, F: np.ndarray) -> tuple[float, int]:
    """Median SED to F of SIFT + MAGSAC++ inliers on two float images in [0, 1]."""
    from fviz.estimators.features import FeatureConfig, detect, match

    cfg = FeatureConfig()
    u8 = [(np.clip(x, 0, 1) * 255).round().astype(np.uint8) for x in (a, b)]
    m = match(detect(u8[0], cfg), detect(u8[1], cfg), cfg)
    _, mask = cv2.findFundamentalMat(m.x_a, m.x_b, cv2.USAC_MAGSAC, 1.0, 0.999, 10000)
    inl = mask.ravel().astype(bool)
    return float(np.median(symmetric_epipolar_distance(F, m.x_a[inl], m.x_b[inl]))), int(inl.sum())


@pytest.mark.parametrize("name, kind, cams, step, tol_px", [
    ("00", "stereo", (0, 1), 0, 0.6),      # gray stereo
    ("05", "stereo", (2, 3), 0, 0.6),      # colour stereo
    ("01", "stereo", (1, 2), 0, 0.6),      # cross-camera, gray right -> colour left
    ("01", "temporal", (0, 0), 1, 1.5),    # gray temporal (poses: a few px at full size)
    ("10", "temporal", (2, 2), 2, 1.5),    # colour-only sequence, gap 2
])
def test_augmented_real_pairs_agree_with_image_matches(kitti_root, name, kind, cams, step, tol_px):
    """On real pairs, every augmentation at once: SIFT + MAGSAC++ inliers of the augmented images lie on
    the augmented ground truth (at 188 x 620, half KITTI's size: the tolerances are the README's, halved)."""
    from fviz.data.kitti import open_dataset

    ds = open_dataset(kitti_root, sequence=name)
    item = KittiItem(str(kitti_root), "sequence", name, 0, kind, step, cams)
    pair = load_kitti_pair(ds, item)
    for seed in range(3):
        rng = np.random.default_rng(seed)
        a, b, F = augmented_pair(pair.image_a, pair.image_b, pair.F_gt, (188, 620), EVERYTHING, rng)
        sed, n = _matched_sed(a, b, F)
        assert n >= 30 and sed < tol_px, (seed, sed, n)


def test_pair_selection_across_sequences_cameras_and_directions(kitti_root, tmp_path):
    recipe = _recipe(kitti_root, tmp_path, sequences=["10"], kinds=["temporal", "stereo"], cameras=[0, 1, 2, 3],
                     steps=[1, 2], both_directions=True)
    items = kitti_items(recipe, "10")  # colour left only: image_2, 10 frames, no stereo partner
    assert {i.cams for i in items} == {(2, 2)} and {i.kind for i in items} == {"temporal"}
    assert len(items) == 2 * (9 + 8)
    ds = KittiPairs(items, (64, 208), "fbn")
    fwd, back = items.index(KittiItem(str(kitti_root), "sequence", "10", 3, "temporal", 2, (2, 2), False)), \
        items.index(KittiItem(str(kitti_root), "sequence", "10", 3, "temporal", 2, (2, 2), True))
    a1, b1, F1 = ds[[fwd]]
    a2, b2, F2 = ds[[back]]
    np.testing.assert_array_equal(a1.numpy(), b2.numpy())
    assert f_distance(F2[0].numpy().astype(np.float64), F1[0].numpy().T.astype(np.float64)) < 1e-5
    raw = kitti_items(_recipe(kitti_root, tmp_path, drives=["2011_09_26_drive_0001"], kinds=["temporal", "stereo"],
                              cameras=[0, 1, 2, 3]), "2011_09_26_drive_0001")
    # raw 0001: stereo only (an oxts packet for frame 0 only)
    assert {i.cams for i in raw} == {(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)}
    assert {i.kind for i in raw} == {"stereo"}


def test_a_held_out_sequence_cannot_be_trained_on(kitti_root, tmp_path):
    recipe = _recipe(kitti_root, tmp_path, sequences=["00", "04"], val_sequences=["04"])
    with pytest.raises(FvizError, match=r"val_sequences \['04'\] are also training sequences"):
        make_datasets(recipe)


def test_several_roots(kitti_root, tmp_path):
    recipe = _recipe(tmp_path / "nothing-here", tmp_path, roots=[str(kitti_root)], sequences=["02"], val_sequences=["09"],
                     cameras=[2])
    (tmp_path / "nothing-here").mkdir()
    train_ds, val_ds = make_datasets(recipe)
    assert {i.name for i in train_ds.items} == {"02"} and {i.name for i in val_ds.items} == {"09"}
    with pytest.raises(FvizError, match="'33' is in none of the roots"):
        kitti_items(_recipe(kitti_root, tmp_path, sequences=["33"]), "33")


def test_ground_truth_agreement_filter(kitti_root, tmp_path):
    """The sample README: stereo GT agrees with the images to < 0.5 px; sequence 00 at gaps of 3-9 frames
    near frames 7-10 does not (2-10 px; 00 f5 -> f10 measured 9.8 px).  The filter keeps the first and
    drops the second, and caches."""
    from fviz.data.kitti import open_dataset

    ds = open_dataset(kitti_root, sequence="00")
    root = str(kitti_root)
    good = KittiItem(root, "sequence", "00", 0, "stereo", 0, (0, 1))
    bad = KittiItem(root, "sequence", "00", 5, "temporal", 5, (0, 0))
    g, b = gt_agreement_px(load_kitti_pair(ds, good)), gt_agreement_px(load_kitti_pair(ds, bad))
    assert g < 0.5 and b > 4.0, (g, b)
    reverse = KittiItem(root, "sequence", "00", 0, "stereo", 0, (0, 1), True)
    cache = tmp_path / "gt.json"
    kept, figures = filter_by_gt_agreement([good, reverse, bad], 1.5, cache)
    assert kept == [good, reverse] and len(figures) == 2 and cache.is_file()
    kept2, _ = filter_by_gt_agreement([good, bad], 1.5, cache)
    assert kept2 == [good]


def test_pose_figures_from_f_against_closed_forms(kitti_root):
    """The held-out figures are the eval's (one meaning per key: rot_err_deg is fviz.evaluate's, the pose recovered
    by cheirality), plus yaw from E = K_b^T F K_a: exact for the ground truth of real temporal pairs; the GT rotation
    angle is the straight-ahead constant's (R = I) rotation error."""
    import math

    from fviz.data.kitti import open_dataset
    from fviz.evaluate import evaluate_pair
    from fviz.train.heldout import pair_figures, straight_ahead_f, yaw_deg, yaw_of_f

    ds = open_dataset(kitti_root, sequence="00")
    for frame in (0, 20, 40):
        pair = ds.pair(frame, kind="temporal", step=1)
        figs = pair_figures(pair, [("constant", straight_ahead_f)])
        assert abs(yaw_of_f(pair.F_gt, pair.K_a, pair.K_b) - yaw_deg(pair.R)) < 1e-5
        assert figs["gt"].metrics["rot_err_deg"] == 0.0
        assert abs(figs["gt"].metrics["yaw_deg"] - yaw_deg(pair.R)) < 1e-5
        angle = math.degrees(math.acos(min((np.trace(pair.R) - 1) / 2, 1.0)))
        assert abs(figs["constant"].metrics["rot_err_deg"] - angle) < 0.02  # acos: KITTI rounding
        evaluated = evaluate_pair(pair, [("constant", straight_ahead_f)]).get("constant").metrics
        np.testing.assert_equal({k: figs["constant"].metrics[k] for k in evaluated}, evaluated)  # NaN == NaN
    c, s = math.cos(math.radians(2.0)), math.sin(math.radians(2.0))
    assert abs(yaw_deg(np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])) - 2.0) < 1e-12  # optical axis towards +x


def test_training_reports_the_held_out_figures(kitti_root, tmp_path):
    """A KITTI recipe with a held-out sequence ends with the eval's figures of model.pt on it (heldout.json,
    printed): here 3 temporal pairs of colour-only 10; the constant's rotation error is the GT rotation angle."""
    import json
    import math

    from cli_util import TINY_MODEL_TOML, run_fviz

    from fviz.data.kitti import open_dataset

    recipe = tmp_path / "k.toml"
    recipe.write_text(f"""
{TINY_MODEL_TOML}[data]
source = "kitti-odometry"
root = "{kitti_root}"
sequences = ["02"]
val_sequences = ["10"]
cameras = [2]
frames = [0, 4]
[train]
batch_size = 2
max_steps = 2
num_workers = 0
out_dir = "{tmp_path / 'run'}"
""")
    proc = run_fviz("train", recipe, timeout=600)
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "run" / "heldout.json").read_text())
    assert "held-out 10, model" in proc.stderr and "held-out 10, constant" in proc.stderr
    assert report["sequences"] == ["10"] and report["model"]["temporal_pairs"] == 3 == report["constant"]["temporal_pairs"]
    ds = open_dataset(kitti_root, sequence="10")
    R = [load_kitti_pair(ds, KittiItem(str(kitti_root), "sequence", "10", f, "temporal", 1, (2, 2))).R for f in range(3)]
    angles = [math.degrees(math.acos(min((np.trace(r) - 1) / 2, 1.0))) for r in R]
    assert abs(report["constant"]["temporal_rot_err_median"] - float(np.median(angles))) < 0.02
    for key in ("temporal_sed_median", "temporal_rot_err_median", "temporal_yaw_corr", "epi_abs"):
        assert key in report["model"]
