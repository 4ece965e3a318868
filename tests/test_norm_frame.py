"""Networks that normalize F in the unrectified cameras' frame (``model.norm_frame = "unrectified"``): where a rectified
KITTI stereo pair's F33 != 0 and ETR is defined, so Table 1's ETR rows can be trained (issue 43). The frame is checked
against an F built in this file straight from the calibration's K, R, T, on the shared raw drive 0001."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from fviz.errors import FvizError
from fviz.geometry import f_distance
from fviz.models.model import FNet
from fviz.models.normalization import normalize_in_frame
from fviz.models.predict import f_to_input
from fviz.train.losses import f_loss
from fviz.train.recipe import Recipe
from fviz.train.splits import make_datasets, network_config, unrectified_frame

DRIVE = "2011_09_26_drive_0001"
HW = (48, 160)
TINY = {"input_size": list(HW), "width": 8, "hidden": 16, "pool_grid": [2, 4], "dropout": 0.0}


def _recipe(kitti_root, tmp_path, variant="siamese-rec-pos-etr", **data) -> Recipe:
    return Recipe.from_dict({
        "model": {"variant": variant, "norm_frame": "unrectified", **TINY},
        "data": {"source": "kitti-raw", "root": str(kitti_root / "raw"), "drives": [DRIVE], "kinds": ["stereo"],
                 "cameras": [0, 1], "both_directions": True, "frames": [0, 6], "val_fraction": 0.3, **data},
        "train": {"out_dir": str(tmp_path / "run"), "batch_size": 4, "max_steps": 2, "num_workers": 0, "val_every": 2,
                  "watch_pairs": 0},
    })


def _calibration(path) -> dict[str, np.ndarray]:
    out = {}
    for line in path.read_text().splitlines():
        key, _, rest = line.partition(":")
        try:
            out[key] = np.array([float(v) for v in rest.split()])
        except ValueError:
            pass
    return out


def _direct_f(calib: dict, a: int, b: int) -> np.ndarray:
    """F of the unrectified cameras a -> b from K_0x, R_0x, T_0x (camera 0 -> x), unrectified full-resolution pixels."""
    K = {c: calib[f"K_0{c}"].reshape(3, 3) for c in (a, b)}
    R = {c: calib[f"R_0{c}"].reshape(3, 3) for c in (a, b)}
    T = {c: calib[f"T_0{c}"] for c in (a, b)}
    R_ab = R[b] @ R[a].T
    t = T[b] - R_ab @ T[a]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return np.linalg.inv(K[b]).T @ tx @ R_ab @ np.linalg.inv(K[a])


def _resize(src_wh, dst_wh) -> np.ndarray:
    """x_dst = S x_src for an OpenCV resize (pixel centres at integers)."""
    sx, sy = dst_wh[0] / src_wh[0], dst_wh[1] / src_wh[1]
    return np.array([[sx, 0, (sx - 1) / 2], [0, sy, (sy - 1) / 2], [0, 0, 1.0]])


def _frame(values) -> tuple[np.ndarray, np.ndarray]:
    U = np.asarray(values, float).reshape(2, 3, 3)
    return U[0], U[1]


def test_the_frame_is_the_unrectified_cameras_at_the_input_scale(kitti_root, raw_drive, tmp_path):
    U_a, U_b = _frame(unrectified_frame(_recipe(kitti_root, tmp_path)))
    pair = raw_drive.pair(2, "stereo", cams=(0, 1))
    F_in = f_to_input(pair.F_gt, pair.size_a, pair.size_b, HW)
    G = np.linalg.inv(U_b).T @ F_in @ np.linalg.inv(U_a)  # the pair's F in the frame, at the input's scale
    S = _resize((1392, 512), (HW[1], HW[0]))  # the unrectified images (S_00 / S_01) resized to the input
    direct = _direct_f(_calibration(raw_drive.calib_path), 0, 1)
    assert f_distance(S.T @ G @ S, direct) < 1e-4
    assert abs(pair.F_gt[2, 2]) < 1e-12  # rectified: ETR undefined
    assert abs(G[2, 2]) / np.linalg.norm(G) > 0.3  # in the frame F33 is a large part of F: ETR is defined


def test_etr_targets_on_raw_stereo_are_normalized_in_the_frame(kitti_root, raw_drive, tmp_path):
    recipe = _recipe(kitti_root, tmp_path)
    train_ds, val_ds = make_datasets(recipe)
    U_a, U_b = _frame(unrectified_frame(recipe))
    directions = set()
    for ds in (train_ds, val_ds):
        for i, item in enumerate(ds.items):
            _, _, F_t = ds[[i]]
            F_t = F_t[0].double().numpy()
            pair = raw_drive.pair(item.frame, "stereo", cams=(0, 1))
            F_gt = pair.F_gt.T if item.reverse else pair.F_gt
            assert f_distance(F_t, f_to_input(F_gt, pair.size_a, pair.size_b, HW)) < 1e-5  # the same geometry
            G = np.linalg.inv(U_b).T @ F_t @ np.linalg.inv(U_a)
            assert abs(G[2, 2] - 1.0) < 1e-5  # ETR: the frame's F33 is 1
            directions.add(item.reverse)
    assert directions == {False, True}

    recipe.model.norm_frame = "input"  # the images' own pixels: F33 = 0, refused in one line
    with pytest.raises(FvizError, match="ETR normalization is undefined for rectified stereo.*norm_frame = 'unrectified'"):
        make_datasets(recipe)
    odometry = _recipe(kitti_root, tmp_path, source="kitti-odometry", root=str(kitti_root), drives=[], sequences=["00"])
    with pytest.raises(FvizError, match="norm_frame = 'unrectified' needs data.source = 'kitti-raw'"):
        make_datasets(odometry)


@pytest.mark.parametrize("variant", ["siamese-rec-pos-etr", "single-base-abs", "siamese-epi-fbn"])
def test_a_model_normalizes_in_its_frame_and_answers_in_input_pixels(kitti_root, tmp_path, variant):
    from fviz.models.weights import load_model
    from fviz.train.checkpoint import save_checkpoint

    recipe = _recipe(kitti_root, tmp_path, variant)
    config = network_config(recipe)
    U_a, U_b = _frame(config.norm_frame)
    torch.manual_seed(0)
    model = FNet.from_config(config).eval()
    img = torch.rand(2, 1, *HW)
    with torch.no_grad():
        F = model(img, img.flip(0)).double().numpy()
        raw = model.unnormalized(img, img.flip(0)).double().numpy()
    norm = variant.rsplit("-", 1)[1]
    for f, r in zip(F, raw):
        assert f_distance(f, r) < 1e-5  # the frame changes the scale only, never the geometry
        G = np.linalg.inv(U_b).T @ f @ np.linalg.inv(U_a)
        if norm == "etr":
            assert abs(G[2, 2] - 1) < 1e-4
        elif norm == "fbn":
            assert abs(np.linalg.norm(G) - 1) < 1e-4
        else:
            assert abs(np.abs(G).max() - 1) < 1e-4
    path = save_checkpoint(tmp_path / "ck.pt", model)
    loaded, _ = load_model(path)
    assert loaded.config.norm_frame == config.norm_frame
    with torch.no_grad():
        np.testing.assert_allclose(loaded(img, img.flip(0)).double().numpy(), F, rtol=1e-5, atol=1e-7)


def test_the_etr_loss_measures_the_direction_where_the_centres_residual_is_zero():
    """In the loss's centred frame F33 = c_b^T F c_a, 0 for a horizontal stereo F: dividing by it made a 1e-4 change
    of F cost like a wrong F. Now the loss grows with the change, and -F (the same F) costs nothing."""
    F = torch.tensor([[[0.0, 0, 0], [0, 0, -1], [0, 1, 0]]], dtype=torch.float64)  # y_b = y_a, input pixels
    shift = torch.eye(3, dtype=torch.float64)
    shift[1, 2] = 0.5  # the frame: image a half a pixel lower, so the frame's F33 != 0 and ETR is defined
    frame = (shift, torch.eye(3, dtype=torch.float64))
    F_t = normalize_in_frame(F, "etr", frame)
    E = torch.tensor([[[0.0, -1e-3, 0], [1e-3, 0, -0.1], [0, 0.1, 2.0]]], dtype=torch.float64)  # a small rotation, a shift
    losses = []
    for eps in (1e-4, 1e-3, 1e-2):
        F_p = normalize_in_frame(F + eps * E, "etr", frame, strict=False)
        losses.append(float(f_loss(F_p, F_t, "etr", frame="conditioned", input_hw=HW)))
    assert all(math.isfinite(v) for v in losses) and losses[0] < 1e-3
    assert losses[0] < losses[1] < losses[2]
    assert float(f_loss(-F_t, F_t, "etr", frame="conditioned", input_hw=HW)) < 1e-12


def test_the_etr_loss_has_no_jump_where_the_networks_f33_crosses_zero():
    """ETR divides by F33 in its frame: as a network's F33 crosses 0 the normalized F flips sign. The conditioned loss
    compared it with the sign kept and jumped there (5 of 12 ETR networks of Table 1 stuck on the wrong side); now the
    loss just before and just after the crossing agree, and the target itself, reached from either side, costs 0."""
    shift = torch.eye(3, dtype=torch.float64)
    shift[1, 2] = 0.5
    frame = (shift, torch.eye(3, dtype=torch.float64))
    U_a_inv = torch.linalg.inv(shift)
    F_t = normalize_in_frame(torch.tensor([[[0.0, 0, 0], [0, 0, -1], [0, 1, 0]]], dtype=torch.float64), "etr", frame)
    e33 = torch.zeros(1, 3, 3, dtype=torch.float64)
    e33[0, 2, 2] = 1.0
    wrong = torch.tensor([[[0.0, 1e-3, 0.2], [0, 0, -1], [0, 1, 0]]], dtype=torch.float64)  # a wrong F
    wrong_frame = wrong @ U_a_inv  # in the frame (U_b = I)
    base = wrong_frame - wrong_frame[0, 2, 2] * e33  # its F33 set to 0 in the frame
    for F_raw_frame in (base, F_t @ U_a_inv):  # a wrong F and the target, each crossing F33 = 0 at +-1e-6
        near = []
        for s in (-1e-6, 1e-6):
            F_raw = (F_raw_frame - F_raw_frame[0, 2, 2] * e33 + s * e33) @ shift
            F_p = normalize_in_frame(F_raw, "etr", frame, strict=False)
            near.append(float(f_loss(F_p, F_t, "etr", frame="conditioned", input_hw=HW)))
        assert abs(near[0] - near[1]) < 1e-3 * max(near[0], 1e-3), near
    assert float(f_loss(normalize_in_frame(-F_t, "etr", frame, strict=False), F_t, "etr", frame="conditioned",
                        input_hw=HW)) < 1e-12


def test_an_etr_network_trains_on_raw_stereo_and_scores_in_the_papers_frame(kitti_root, raw_drive, tmp_path, torch_one_thread):
    from fviz.data.kitti import raw_cameras
    from fviz.estimators.deep import deep_estimator
    from fviz.evaluate import evaluate_pair, rows_in_frame
    from fviz.train import train

    result = train(_recipe(kitti_root, tmp_path), record=False, held_out=False)
    assert result.weights is not None and result.weights.is_file()
    pair = raw_drive.pair(5, "stereo", cams=(0, 1))
    evaluated = evaluate_pair(pair, [("net", deep_estimator(result.weights))])
    assert evaluated.get("net").F is not None, evaluated.get("net").error
    cams = raw_cameras(raw_drive.calib_path)
    rows = {r["estimator"]: r for r in rows_in_frame(evaluated, cams[0].H, cams[1].H, rule="paper")}
    assert math.isfinite(float(rows["net"]["epi_abs_etr"])) and math.isfinite(float(rows["gt"]["epi_abs_etr"]))


def test_in_the_conditioned_frame_etr_and_fbn_train_on_one_loss():
    """F / F33 and F / ||F|| differ only in scale and sign, and the conditioned loss removes both: a network's raw F
    gets the same loss and the same gradient under either layer (ETR's cells then differ from FBN's in the output's
    scale, what EPI-ABS / EPI-SQR measure)."""
    g = torch.Generator().manual_seed(5)
    shift = torch.eye(3, dtype=torch.float64)
    shift[:2, 2] = torch.tensor([40.0, -7.0])
    frame = (shift, torch.eye(3, dtype=torch.float64))
    F_t = torch.tensor([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]], dtype=torch.float64) + 1e-3 * torch.randn(6, 3, 3, generator=g,
                                                                                                      dtype=torch.float64)
    raw = torch.randn(6, 3, 3, generator=g, dtype=torch.float64)
    out = {}
    for norm in ("etr", "fbn"):
        F = raw.clone().requires_grad_(True)
        loss = f_loss(normalize_in_frame(F, norm, frame, strict=False), normalize_in_frame(F_t, norm, frame), norm,
                      frame="conditioned", input_hw=HW)
        loss.backward()
        out[norm] = (float(loss.detach()), F.grad)
    assert out["etr"][0] == pytest.approx(out["fbn"][0], rel=1e-6)
    scale = float(out["fbn"][1].abs().max())  # f_loss computes in float32
    torch.testing.assert_close(out["etr"][1], out["fbn"][1], rtol=1e-4, atol=1e-5 * scale)
