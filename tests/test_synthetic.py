"""Synthetic KITTI-like pairs: exact ground truth, determinism, stereo, texture, occlusion, config."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from fviz.data import synthetic as syn
from fviz.data.synthetic import SceneConfig, intrinsics, render_batch, synthetic_pair
from fviz.errors import FvizError
from fviz.geometry import f_distance, homogeneous, symmetric_epipolar_distance


@pytest.fixture(scope="module")
def temporal():
    return synthetic_pair(3)


@pytest.fixture(scope="module")
def stereo():
    return synthetic_pair(4, SceneConfig(stereo=True))


@pytest.fixture(scope="module", params=["temporal", "stereo"])
def pair(request, temporal, stereo):
    return temporal if request.param == "temporal" else stereo


def test_pair_fields(temporal):
    p = temporal
    assert p.id.source == "synthetic" and p.id.sequence == "3" and p.id.kind == "temporal"
    assert (p.id.frame_a, p.id.frame_b, p.id.cam_a, p.id.cam_b) == (0, 1, 0, 0)
    assert p.image_a.shape == p.image_b.shape == (375, 1242) and p.image_a.dtype == np.uint8
    assert p.gt_accuracy_px == 0.0
    assert p.points_a.dtype == p.points_b.dtype == np.float64 and p.points_a.shape == p.points_b.shape
    np.testing.assert_allclose(p.K_a, [[718.856, 0, 607.1928], [0, 718.856, 185.2157], [0, 0, 1]])
    np.testing.assert_allclose(p.R @ p.R.T, np.eye(3), atol=1e-12)
    assert 0.3 <= np.linalg.norm(p.t) <= 2.0
    assert abs(np.linalg.norm(p.F_gt) - 1.0) < 1e-12


def test_correspondences_are_exact(pair):
    xa, xb, F = pair.points_a, pair.points_b, pair.F_gt
    assert len(xa) > 500
    Fxa = homogeneous(xa) @ F.T
    rel = np.abs(np.einsum("ni,ni->n", homogeneous(xb), Fxa)) / (
        np.linalg.norm(homogeneous(xb), axis=1) * np.linalg.norm(Fxa, axis=1)
    )
    assert rel.max() < 1e-6
    assert symmetric_epipolar_distance(F, xa, xb).max() < 1e-4
    assert (xb >= -0.5).all() and (xb[:, 0] < 1241.5).all() and (xb[:, 1] < 374.5).all()  # inside image b


def test_f_agrees_with_opencv_8point(pair):
    F_cv, _ = cv2.findFundamentalMat(pair.points_a, pair.points_b, cv2.FM_8POINT)
    assert F_cv is not None and F_cv.shape == (3, 3)
    assert f_distance(F_cv, pair.F_gt) < 1e-3


def test_determinism_and_batch_equals_single(temporal):
    again = synthetic_pair(3)
    assert np.array_equal(again.image_a, temporal.image_a) and np.array_equal(again.image_b, temporal.image_b)
    assert np.array_equal(again.F_gt, temporal.F_gt) and np.array_equal(again.points_b, temporal.points_b)
    other = synthetic_pair(5)
    assert not np.array_equal(other.image_a, temporal.image_a)
    assert f_distance(other.F_gt, temporal.F_gt) > 1e-3

    batch = render_batch([11, 3], SceneConfig())
    to_u8 = lambda x: (x * 255.0).round().to(torch.uint8).numpy()  # noqa: E731
    assert np.array_equal(to_u8(batch["image_a"][1, 0]), temporal.image_a)
    assert np.array_equal(to_u8(batch["image_b"][1, 0]), temporal.image_b)
    assert np.allclose(batch["F"][1].numpy(), temporal.F_gt, atol=1e-15)
    assert not torch.equal(batch["image_a"][0], batch["image_a"][1])


def test_render_batch_outputs():
    cfg = SceneConfig(width=320, height=96, blur_sigma=0.8, noise_sigma=2.0)
    out = render_batch(torch.tensor([1, 2]), cfg, with_depth=True)
    assert out["image_a"].shape == out["image_b"].shape == (2, 1, 96, 320) and out["image_a"].dtype == torch.float32
    assert 0.0 <= out["image_a"].min() and out["image_b"].max() <= 1.0
    assert torch.equal(out["image_a"], (out["image_a"] * 255).round() / 255)  # uint8 levels
    for key, shape in [("F", (2, 3, 3)), ("K_a", (2, 3, 3)), ("K_b", (2, 3, 3)), ("R", (2, 3, 3)), ("t", (2, 3))]:
        assert out[key].shape == shape, key
    np.testing.assert_allclose(out["K_a"][0].numpy(), intrinsics(320, 96))
    assert intrinsics(320, 96)[0, 0] == pytest.approx(718.856 * 320 / 1242)
    assert out["depth_a"].shape == (2, 1, 96, 320) and torch.isinf(out["depth_a"]).any()  # sky
    assert (out["depth_a"][torch.isfinite(out["depth_a"])] > 0).all()
    # F of the batch is the normalized F of its motion
    K, R, t = out["K_a"][0].numpy(), out["R"][0].numpy(), out["t"][0].numpy()
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    assert f_distance(np.linalg.inv(K).T @ tx @ R @ np.linalg.inv(K), out["F"][0].numpy()) < 1e-12
    # the same batch again is identical (noise included)
    assert torch.equal(render_batch([1, 2], cfg)["image_b"], out["image_b"])


def test_stereo(stereo):
    p = stereo
    assert p.id.kind == "stereo" and (p.id.cam_a, p.id.cam_b) == (0, 1)
    assert np.array_equal(p.R, np.eye(3))
    np.testing.assert_array_equal(p.t, [-0.54, 0.0, 0.0])
    assert abs(p.F_gt[2, 2]) < 1e-12  # rectified: F33 = 0
    np.testing.assert_allclose(p.points_a[:, 1], p.points_b[:, 1], atol=1e-9)  # same rows
    assert (p.points_b[:, 0] <= p.points_a[:, 0] + 1e-9).all()  # positive disparity


def _sift_inliers(p, ratio: float = 0.8) -> int:
    sift = cv2.SIFT_create(nfeatures=3000)  # the strongest ones: keeps the matching quick
    ka, da = sift.detectAndCompute(p.image_a, None)
    kb, db = sift.detectAndCompute(p.image_b, None)
    good = [m for m, n in cv2.BFMatcher().knnMatch(da, db, k=2) if m.distance < ratio * n.distance]
    xa = np.float64([ka[m.queryIdx].pt for m in good])
    xb = np.float64([kb[m.trainIdx].pt for m in good])
    return int((symmetric_epipolar_distance(p.F_gt, xa, xb) < 1.0).sum())


def test_texture_is_usable_by_sift(temporal):
    assert temporal.image_a.std() > 20 and temporal.image_b.std() > 20
    assert _sift_inliers(temporal) > 100


def test_occlusion_hides_points_behind_boxes():
    p = synthetic_pair(10, SceneConfig(n_boxes=8))
    e = p.extra
    occ_a, occ_b = e["occluded_a"], e["occluded_b"]
    assert e["n_inside_b"] == len(p.points_a) + len(occ_a) and e["n_hit"] <= e["n_sampled"]
    assert len(occ_a) >= 20  # a box in front hides part of what a sees
    # Independent check with the rendered depth maps: what b sees at an occluded point is nearer.
    K_inv = np.linalg.inv(p.K_a)

    def z_in_b(xa):
        ij = np.round(xa).astype(int)
        depth = e["depth_a"][ij[:, 1], ij[:, 0]]
        depth = np.where(np.isfinite(depth), depth, np.nan)
        return ((depth[:, None] * (homogeneous(xa) @ K_inv.T)) @ p.R.T + p.t)[:, 2]

    def depth_b(xb):
        ij = np.clip(np.round(xb).astype(int), 0, [p.size_b[0] - 1, p.size_b[1] - 1])
        return e["depth_b"][ij[:, 1], ij[:, 0]]

    z_occ, z_vis = z_in_b(occ_a), z_in_b(p.points_a)  # nan next to the sky (nearest pixel is sky)
    ok_occ, ok_vis = np.isfinite(z_occ), np.isfinite(z_vis)
    assert ok_occ.mean() > 0.9 and ok_vis.mean() > 0.95
    assert np.mean(depth_b(occ_b[ok_occ]) < 0.97 * z_occ[ok_occ]) > 0.8
    assert np.mean(np.abs(depth_b(p.points_b[ok_vis]) / z_vis[ok_vis] - 1) < 0.03) > 0.95


def test_renderer_agrees_with_direct_ray_casting():
    cfg = SceneConfig(n_boxes=6, width=400, height=120)
    scene = syn._sample_scene(21, cfg)
    out = render_batch([21], cfg, with_depth=True)
    rng = np.random.default_rng(0)
    pix = np.stack([rng.integers(0, 400, 20000), rng.integers(0, 120, 20000)], 1).astype(np.float64)
    for view, key in enumerate(["depth_a", "depth_b"]):
        coef, _, valid = syn._plane_coefficients(scene.planes(view), *scene.cams[view], scene.K)
        inv_z, _ = syn._cast(coef, valid, pix)
        ref = np.where(inv_z > 0, 1.0 / np.where(inv_z > 0, inv_z, 1.0), np.inf)
        got = out[key][0, 0].numpy()[pix[:, 1].astype(int), pix[:, 0].astype(int)]
        assert np.isclose(got, ref, rtol=1e-4).mean() > 0.999


@pytest.mark.parametrize(
    "field, value",
    [
        ("width", 0),
        ("height", 10.5),
        ("stereo", "yes"),
        ("baseline", -0.5),
        ("forward_range", (2.0, 1.0)),
        ("rotation_deg", math.nan),
        ("n_boxes", -1),
        ("facade_segments", 0),
        ("texture_contrast", -1.0),
        ("texture_frequency", 0.0),
        ("noise_sigma", -0.1),
        ("blur_sigma", 100.0),
        ("n_points", 0),
    ],
)
def test_bad_config_names_the_field(field, value):
    with pytest.raises(FvizError, match=field):
        SceneConfig(**{field: value})


def test_bad_seeds():
    with pytest.raises(FvizError, match="seeds"):
        render_batch([], SceneConfig())
    with pytest.raises(FvizError, match="seeds"):
        render_batch([1.5], SceneConfig())
