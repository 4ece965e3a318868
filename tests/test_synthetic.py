"""Synthetic KITTI-like pairs: exact ground truth, determinism, stereo, texture, occlusion, config."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from fviz.data.synthetic import SceneConfig, batch, intrinsics, render_batch, synthetic_pair
from fviz.data.synthetic.consts import scene_consts
from fviz.data.synthetic.draws import mix64, shr
from fviz.data.synthetic.elementwise import sincos
from fviz.data.synthetic.pair_source import _cast, _view_planes
from fviz.data.synthetic.raster import plane_coefficients, render_views
from fviz.data.synthetic.scene import sample_scenes
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
    to_u8 = lambda x: (x * 255.0).round().to(torch.uint8).numpy()
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
    p = synthetic_pair(4, SceneConfig(n_boxes=8))  # a seed whose boxes hide a lot (seeds 0-15: 4-44 points)
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
    coef, valid = _view_planes(21, cfg)
    out = render_batch([21], cfg, with_depth=True)
    rng = np.random.default_rng(0)
    pix = np.stack([rng.integers(0, 400, 20000), rng.integers(0, 120, 20000)], 1).astype(np.float64)
    for view, key in enumerate(["depth_a", "depth_b"]):
        inv_z, _ = _cast(coef[view], valid[view], pix)
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


# ------------------------------------------------- batched sampling: determinism, devices, no syncs


def _small(**kw) -> SceneConfig:
    return SceneConfig(width=160, height=48, **kw)


def test_any_batch_renders_each_seed_alike():
    cfg = _small(blur_sigma=0.7, noise_sigma=3.0, n_boxes=5)
    batch = render_batch([7, 3, 2**63 - 1, 0], cfg, with_depth=True)
    for i, s in enumerate([7, 3, 2**63 - 1, 0]):
        one = render_batch([s], cfg, with_depth=True)
        for k, v in one.items():
            assert torch.equal(batch[k][i], v[0]), (s, k)


def test_scene_stream_and_trig_are_exact_elementwise_maths():
    u = shr(mix64(torch.arange(20000, dtype=torch.int64) * 7919), 11).double() * 2.0**-53
    assert 0.0 <= u.min() and u.max() < 1.0 and abs(u.mean().item() - 0.5) < 0.01
    x = torch.linspace(-4.0, 4.0, 10001, dtype=torch.float64)
    s, c = sincos(x)
    assert (s - torch.sin(x)).abs().max() < 4e-15 and (c - torch.cos(x)).abs().max() < 4e-15
    # a scene's parameters do not depend on the seeds beside it
    cfg = _small()
    c = scene_consts(cfg, torch.device("cpu"))
    one = sample_scenes(torch.tensor([5]), cfg, c)
    two = sample_scenes(torch.tensor([9, 5]), cfg, c)
    assert torch.equal(one["planes"][0], two["planes"][1]) and torch.equal(one["planes"][1], two["planes"][3])


def test_noise_is_independent_between_views():
    cfg = _small(noise_sigma=30.0, texture_contrast=0.0)  # flat surfaces: the images are mostly noise
    flat = render_batch([1], _small(noise_sigma=0.0, texture_contrast=0.0))
    out = render_batch([1], cfg)
    na, nb = ((out[k] - flat[k]).flatten() for k in ("image_a", "image_b"))
    assert 0.08 < na.std() < 0.15 and abs(np.corrcoef(na.numpy(), nb.numpy())[0, 1]) < 0.05


@pytest.mark.parametrize(
    "cfg",
    [
        _small(n_boxes=8),
        _small(n_boxes=0, facade_segments=1, noise_sigma=0.0),
        _small(n_boxes=16, facade_segments=8, stereo=True, blur_sigma=1.0),
    ],
    ids=["boxes", "bare", "crowded-stereo"],
)
def test_gpu_algorithm_renders_the_cpu_pixels(cfg):
    """The sync-free renderer (all views and planes at once, binary search per pixel) that runs on
    GPUs gives exactly the CPU renderer's pixels; checked here on the CPU."""
    c = scene_consts(cfg, torch.device("cpu"))
    sc = sample_scenes(torch.arange(6), cfg, c)
    coef, shade, valid = plane_coefficients(sc["planes"], sc["R_cw"], sc["C"], c.kinv)
    per_view = render_views(coef, shade, valid, sc["sky"], cfg.height, cfg.width, c)
    at_once = render_views(coef, shade, valid, sc["sky"], cfg.height, cfg.width, c, sync_free=True)
    assert all(torch.equal(x, y) for x, y in zip(per_view, at_once))
    out = render_batch(list(range(6)), cfg, with_depth=True)
    assert out["image_a"].shape == (6, 1, 48, 160) and torch.isfinite(out["F"]).all()
    assert (out["depth_a"] > 0).all() and torch.isinf(out["depth_a"]).any()


cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


@cuda
def test_cuda_matches_cpu():
    cfg = _small(n_boxes=5)
    seeds = [3, 11, 12345]
    cpu, gpu = render_batch(seeds, cfg, with_depth=True), render_batch(seeds, cfg, "cuda", with_depth=True)
    for k in ("F", "R", "t", "K_a"):
        assert torch.allclose(gpu[k].cpu(), cpu[k], rtol=0, atol=1e-14), k
    for k in ("image_a", "image_b"):
        diff = (gpu[k].cpu() - cpu[k]).abs() * 255
        assert (diff > 0.5).float().mean() < 1e-3 and (diff > 1.5).float().mean() < 1e-4, k


@cuda
def test_cuda_graph_side_stream_eager_and_batch_agree(monkeypatch):
    cfg = _small(noise_sigma=2.0)
    graphed = render_batch([4, 8, 15], cfg, "cuda")
    busy = torch.randn(4096, 4096, device="cuda")
    for _ in range(20):  # keep the caller's stream busy: the render must still be ordered before its use
        busy = busy @ busy / 64.0
    seeds = torch.arange(3, device="cuda") * 4 + 4  # made on the caller's stream: 4, 8, 12 ...
    seeds[2] = 15
    again = render_batch(seeds, cfg, "cuda")
    monkeypatch.setattr(batch, "CUDA_GRAPHS", False)
    monkeypatch.setattr(batch, "SIDE_STREAM", False)
    eager = render_batch([4, 8, 15], cfg, "cuda")
    single = render_batch([8], cfg, "cuda")
    for k in graphed:
        assert torch.equal(graphed[k], eager[k]) and torch.equal(again[k], eager[k]), k
        assert torch.equal(graphed[k][1], single[k][0]), k


@cuda
@pytest.mark.parametrize("graphs, side", [(True, True), (False, True), (True, False)])
def test_cuda_render_does_not_synchronise(monkeypatch, graphs, side):
    monkeypatch.setattr(batch, "CUDA_GRAPHS", graphs)
    monkeypatch.setattr(batch, "SIDE_STREAM", side)
    cfg = _small()
    render_batch([1, 2], cfg, "cuda")  # first call: allocations, graph capture
    on_gpu = torch.tensor([5, 6], device="cuda")
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        out = render_batch([5, 6], cfg, "cuda")
        again = render_batch(on_gpu, cfg, "cuda")
    finally:
        torch.cuda.set_sync_debug_mode("default")
    assert out["image_a"].shape == (2, 1, 48, 160) and torch.equal(out["image_b"], again["image_b"])


def test_realism_knobs_exposure_and_straight_driving():
    """exposure changes each view's brightness, never the geometry; straight_fraction = 1 cuts every
    rotation to a tenth; at 0.5 about half the scenes drive straight (KITTI-like motion statistics)."""
    from fviz.data.synthetic import SceneConfig, render_batch, synthetic_pair

    base = SceneConfig(width=64, height=32, rotation_deg=3.5, n_points=50)
    for seed in range(3):
        p0 = synthetic_pair(seed, base)
        p1 = synthetic_pair(seed, SceneConfig(width=64, height=32, rotation_deg=3.5, exposure=0.5, n_points=50))
        np.testing.assert_array_equal(p0.F_gt, p1.F_gt)
        np.testing.assert_array_equal(p0.points_b, p1.points_b)
        ratios = [p1.image_a.mean() / p0.image_a.mean(), p1.image_b.mean() / p0.image_b.mean()]
        assert all(0.4 < r < 1.6 for r in ratios) and abs(ratios[0] - ratios[1]) > 1e-3

    def yaws(cfg):
        R = render_batch(list(range(120)), cfg)["R"].numpy()  # tiny images: only the motion matters
        return np.degrees(np.arctan2(R[:, 0, 2], R[:, 2, 2]))

    free = yaws(base)
    assert np.abs(free).max() <= 3.5 + 1e-9 and np.abs(free).max() > 3.0
    straight = yaws(SceneConfig(width=64, height=32, rotation_deg=3.5, straight_fraction=1.0))
    np.testing.assert_allclose(straight, free / 10, rtol=0.05, atol=0.02)  # the same draws, a tenth of the rotation
    half = yaws(SceneConfig(width=64, height=32, rotation_deg=3.5, straight_fraction=0.5))
    share = np.mean(np.isclose(half, free / 10, rtol=0.05, atol=0.02) & (np.abs(free) > 0.5))
    assert np.all(np.isclose(half, free / 10, rtol=0.05, atol=0.02) | np.isclose(half, free))
    assert 0.3 < share / np.mean(np.abs(free) > 0.5) < 0.7
