"""The epipolar geometry written again in torch (the training loop's losses and metrics, the model heads, the synthetic
scenes' ground truth) against the numpy floor, fviz.geometry, on random batches in float64 and float32, and
``torch.autograd.gradcheck`` on the differentiable ones in float64. The normalization layers and the reconstruction
layer on one pair are in tests/test_models.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from fviz.data.synthetic import intrinsics
from fviz.data.synthetic.elementwise import cross, fundamental, mm, rotation, sincos
from fviz.estimators.baselines import mean_fundamental
from fviz.geometry import (
    algebraic,
    enforce_rank2,
    f_distance,
    fundamental_from_motion,
    normalize,
    skew,
    symmetric_epipolar_distance,
    transfer_fundamental,
)
from fviz.models.heads import conditioning_matrix, euler_to_rotation, fundamental_from_params, inverse_intrinsics
from fviz.models.heads import skew as skew_t
from fviz.models.normalization import normalize_f
from fviz.train.losses import _to_conditioned, epipolar_metrics, f_distance_t, f_loss, sample_points_on_geometry, sed_loss
from fviz.train.validation import _rank2, mean_target, straight_ahead_input_f

HW = (48, 160)  # (H, W) of a model input
B, N = 6, 40
TOL = {torch.float64: dict(rtol=1e-10, atol=1e-12), torch.float32: dict(rtol=2e-4, atol=1e-5)}
DTYPES = list(TOL)


def _rotation_np(rng) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _cameras(rng, n: int = B):
    """n random camera pairs of the model input: (K_a, K_b, R, t) and F = K_b^-T [t]x R K_a^-1 (numpy)."""
    H, W = HW
    out = []
    for _ in range(n):
        f_a, f_b = rng.uniform(50, 400, size=2)
        K_a = np.array([[f_a, 0, rng.uniform(0, W)], [0, f_a, rng.uniform(0, H)], [0, 0, 1]])
        K_b = np.array([[f_b, 0, rng.uniform(0, W)], [0, f_b, rng.uniform(0, H)], [0, 0, 1]])
        R, t = _rotation_np(rng), rng.normal(size=3)
        out.append((K_a, K_b, R, t, fundamental_from_motion(K_a, K_b, R, t)))
    return out


def _points(rng, n_pairs: int = B, n: int = N) -> tuple[np.ndarray, np.ndarray]:
    """Random (not corresponding) homogeneous pixels of the input, (n_pairs, n, 3) x 2: residuals far from 0."""
    H, W = HW
    scale = np.array([W - 1, H - 1])
    one = np.ones((n_pairs, n, 1))
    return (np.concatenate([rng.uniform(size=(n_pairs, n, 2)) * scale, one], -1),
            np.concatenate([rng.uniform(size=(n_pairs, n, 2)) * scale, one], -1))


def _unit(F: np.ndarray) -> np.ndarray:
    return F / np.linalg.norm(F.reshape(*F.shape[:-2], 9), axis=-1)[..., None, None]


# ------------------------------------------------------------------------------------ the training loop's geometry


@pytest.mark.parametrize("dtype", DTYPES)
def test_epipolar_metrics_are_the_numpy_sed_and_algebraic_residual(dtype):
    """SED in px (scale-free) and |x_b^T F x_a| of the unit-Frobenius F, per point, for every pair of a batch; F in the
    model's dtype, the points float64 (as sample_points_on_geometry makes them)."""
    rng = np.random.default_rng(0)
    Fs = np.stack([c[4] for c in _cameras(rng)]) * 10 ** rng.uniform(-3, 3, size=(B, 1, 1))
    xa, xb = _points(rng)
    got = epipolar_metrics(torch.from_numpy(Fs).to(dtype), torch.from_numpy(xa), torch.from_numpy(xb))
    for k in range(B):
        np.testing.assert_allclose(got["sed"][k].numpy(), symmetric_epipolar_distance(Fs[k], xa[k, :, :2], xb[k, :, :2]),
                                   **TOL[dtype])
        np.testing.assert_allclose(got["abs"][k].numpy(), algebraic(_unit(Fs[k]), xa[k, :, :2], xb[k, :, :2]), **TOL[dtype])


@pytest.mark.parametrize("dtype", DTYPES)
def test_f_distance_t_is_the_numpy_f_distance(dtype):
    rng = np.random.default_rng(1)
    A = rng.normal(size=(B, 3, 3)) * 10 ** rng.uniform(-3, 3, size=(B, 1, 1))
    Bm = A + rng.normal(size=(B, 3, 3)) * np.abs(A).max() * rng.uniform(0, 0.5, size=(B, 1, 1))
    Bm[::2] *= -1  # up to sign
    got = f_distance_t(torch.from_numpy(A).to(dtype), torch.from_numpy(Bm).to(dtype)).numpy()
    np.testing.assert_allclose(got, f_distance(A, Bm), **TOL[dtype])


@pytest.mark.parametrize("dtype", DTYPES)
def test_rank2_is_the_numpy_closest_rank2_matrix_at_unit_norm(dtype):
    rng = np.random.default_rng(2)
    for F in rng.normal(size=(B, 3, 3)):
        want = enforce_rank2(F)
        np.testing.assert_allclose(_rank2(torch.from_numpy(F).to(dtype)).numpy(), want / np.linalg.norm(want), **TOL[dtype])


def test_mean_target_is_the_numpy_mean_fundamental():
    """The loop's oracle constant (torch) and the mean-F baseline (numpy, fviz.estimators.baselines): the same mean up
    to scale and sign."""
    rng = np.random.default_rng(3)
    Fs = np.stack([c[4] for c in _cameras(rng, 12)]) * np.where(rng.uniform(size=(12, 1, 1)) < 0.5, -1, 1)
    got = mean_target(torch.from_numpy(Fs)).numpy()
    assert f_distance(got, mean_fundamental(Fs)) < 1e-12


def test_straight_ahead_input_f_is_forward_motion_with_the_synthetic_camera():
    for H, W in (HW, (96, 320), (376, 1241)):
        K = intrinsics(W, H)
        want = fundamental_from_motion(K, K, np.eye(3), np.array([0.0, 0.0, 1.0]))
        got = straight_ahead_input_f((H, W)).numpy()
        assert np.linalg.norm(got) == pytest.approx(1.0) and f_distance(got, want) < 1e-12


@pytest.mark.parametrize("norm", ["fbn", "abs", "etr"])
@pytest.mark.parametrize("dtype", DTYPES)
def test_conditioned_frame_is_the_numpy_transfer_and_normalization(norm, dtype):
    """f_loss's conditioned frame: F in coordinates x_n = T x is T^-T F T^-1 (fviz.geometry.transfer_fundamental),
    then normalized as the numpy normalize does; ETR by the Frobenius norm with its sign kept (F33 there is the
    centres' residual, ~0 for stereo and forward motion)."""
    rng = np.random.default_rng(4)
    Fs = np.stack([c[4] for c in _cameras(rng)])
    T = conditioning_matrix(HW, dtype=torch.float64).numpy()
    H, W = HW
    assert np.allclose(T @ [0.0, 0.0, 1.0], [-(W - 1) / W, -(H - 1) / W, 1.0])  # the top-left pixel centre, long side W
    G = transfer_fundamental(Fs, T, T)
    want = G / np.linalg.norm(G, axis=(1, 2), keepdims=True) if norm == "etr" else normalize(G, norm)
    got = _to_conditioned(torch.from_numpy(Fs).to(dtype), HW, norm).double().numpy()
    np.testing.assert_allclose(got, want, **TOL[dtype])


def test_points_sampled_on_the_geometry_have_no_residual_under_numpy():
    rng = np.random.default_rng(5)
    Fs = np.stack([c[4] for c in _cameras(rng)])
    xa, xb = sample_points_on_geometry(torch.from_numpy(Fs), HW, N, torch.Generator().manual_seed(0))
    H, W = HW
    assert xa.dtype == xb.dtype == torch.float64 and xa.shape == (B, N, 3)
    assert (xa[..., 0] >= 0).all() and (xa[..., 0] <= W - 1).all() and (xa[..., 1] >= 0).all() and (xa[..., 1] <= H - 1).all()
    for k in range(B):
        assert symmetric_epipolar_distance(Fs[k], xa[k, :, :2].numpy(), xb[k, :, :2].numpy()).max() < 1e-9


# ----------------------------------------------------------------------------------------------- the model heads


def test_head_matrices_are_the_numpy_ones():
    rng = np.random.default_rng(6)
    t = rng.normal(size=(B, 3))
    np.testing.assert_array_equal(skew_t(torch.from_numpy(t)).numpy(), skew(t))
    f = rng.uniform(20, 500, size=B)
    cx, cy = 79.5, 23.5
    K = np.stack([np.array([[v, 0, cx], [0, v, cy], [0, 0, 1]]) for v in f])
    np.testing.assert_allclose(inverse_intrinsics(torch.from_numpy(f), cx, cy).numpy(), np.linalg.inv(K), rtol=1e-12, atol=1e-15)
    R = euler_to_rotation(torch.from_numpy(rng.normal(0, 0.5, size=(B, 3)))).numpy()
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)


@pytest.mark.parametrize("dtype", DTYPES)
def test_the_reconstruction_layer_on_a_batch_is_fundamental_from_motion(dtype):
    rng = np.random.default_rng(7)
    H, W = HW
    cx, cy = (W - 1) / 2, (H - 1) / 2
    f_a, f_b = rng.uniform(50, 400, size=(2, B))
    ang, t = rng.normal(0, 0.3, size=(B, 3)), rng.normal(size=(B, 3))
    R = euler_to_rotation(torch.from_numpy(ang)).numpy()
    K = lambda f: np.stack([np.array([[v, 0, cx], [0, v, cy], [0, 0, 1]]) for v in f])
    want = fundamental_from_motion(K(f_a), K(f_b), R, t)
    got = fundamental_from_params(*(torch.from_numpy(v).to(dtype) for v in (f_a, f_b, ang, t)), cx, cy).double().numpy()
    np.testing.assert_allclose(_unit(got), _unit(want), **TOL[dtype])


# ----------------------------------------------------------------------------------- the synthetic scenes' truth


def test_synthetic_ground_truth_f_is_the_numpy_one_fbn_normalized():
    """The scenes' F, built from + - * only (the same bits on every device): fundamental_from_motion, then FBN."""
    rng = np.random.default_rng(8)
    K = intrinsics(320, 96)
    R = np.stack([_rotation_np(rng) for _ in range(B)])
    t = rng.normal(size=(B, 3))
    got = fundamental(torch.from_numpy(R), torch.from_numpy(t), torch.from_numpy(np.linalg.inv(K))).numpy()
    np.testing.assert_allclose(got, normalize(fundamental_from_motion(K, K, R, t), "fbn"), rtol=1e-10, atol=1e-13)


def test_synthetic_small_matrix_helpers_are_numpy_s():
    rng = np.random.default_rng(9)
    a, b = rng.normal(size=(2, B, 3))
    A, M = rng.normal(size=(2, B, 3, 3))
    np.testing.assert_allclose(cross(torch.from_numpy(a), torch.from_numpy(b)).numpy(), np.cross(a, b), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(mm(torch.from_numpy(A), torch.from_numpy(M)).numpy(), A @ M, rtol=1e-12, atol=1e-14)
    x = np.linspace(-4, 4, 1001)
    s, c = sincos(torch.from_numpy(x))
    np.testing.assert_allclose(s.numpy(), np.sin(x), atol=1e-14)
    np.testing.assert_allclose(c.numpy(), np.cos(x), atol=1e-14)
    yaw, pitch, roll = rng.uniform(-0.5, 0.5, size=(3, B))
    ang = np.stack([yaw, pitch, roll], -1)
    got = rotation(torch.from_numpy(np.sin(ang)), torch.from_numpy(np.cos(ang))).numpy()

    def rot(axis, v):
        c, s = math.cos(v), math.sin(v)
        return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
                "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]

    want = np.stack([rot("y", y) @ rot("x", p) @ rot("z", r) for y, p, r in ang])
    np.testing.assert_allclose(got, want, atol=1e-14)


# ---------------------------------------------------------------------------------------------------- gradients
# On a small image (pixels of a few units, F of O(1) entries): finite differences of step 1e-6 stay in the linear range.

SMALL_HW = (4, 6)


def _gradcheck(fn, *inputs, float32_inside: bool = False):
    """gradcheck in float64; a loss that computes in float32 (f_loss, sed_loss's result) at float32's precision."""
    inputs = tuple(torch.as_tensor(v, dtype=torch.float64).requires_grad_(True) for v in inputs)
    tol = dict(eps=1e-3, atol=1e-3, rtol=1e-2) if float32_inside else dict(eps=1e-6, atol=1e-6, rtol=1e-5)
    assert torch.autograd.gradcheck(fn, inputs, **tol)


def _small(rng, n_pairs: int = 2, n: int = 5):
    """F of O(1) entries, pixels in a 6 x 4 image: (n_pairs, 3, 3), (n_pairs, n, 3) x 2."""
    one = np.ones((n_pairs, n, 1))
    pts = [np.concatenate([rng.uniform(size=(n_pairs, n, 2)) * [5, 3], one], -1) for _ in range(2)]
    return rng.normal(size=(n_pairs, 3, 3)), *pts


def test_gradients_of_the_losses_and_metrics():
    rng = np.random.default_rng(10)
    Fs, xa, xb = _small(rng)
    _gradcheck(lambda F, a, b: epipolar_metrics(F, a, b)["sed"], Fs, xa, xb)
    _gradcheck(lambda F, a, b: epipolar_metrics(F, a, b)["abs"], Fs, xa, xb)
    _gradcheck(lambda F: sed_loss(F, torch.from_numpy(xa), torch.from_numpy(xb)).double(), Fs, float32_inside=True)
    target = torch.from_numpy(normalize(Fs + 0.1 * rng.normal(size=Fs.shape), "fbn"))
    _gradcheck(lambda F: f_distance_t(F, target), Fs)
    _gradcheck(lambda F: _rank2(F), Fs[0])


@pytest.mark.parametrize("norm", ["fbn", "abs", "etr"])
def test_gradients_of_the_normalization_and_the_conditioned_frame(norm):
    rng = np.random.default_rng(11)
    Fs = _small(rng)[0]
    _gradcheck(lambda F: normalize_f(F, norm, strict=False), Fs)
    _gradcheck(lambda F: _to_conditioned(F, SMALL_HW, norm), Fs)
    target = torch.from_numpy(Fs + 0.1 * rng.normal(size=Fs.shape))
    _gradcheck(lambda F: f_loss(F, target, norm, frame="conditioned", input_hw=SMALL_HW).double(), Fs, float32_inside=True)


def test_gradients_of_the_reconstruction_layer():
    rng = np.random.default_rng(12)
    H, W = SMALL_HW
    _gradcheck(lambda fa, fb, ang, t: fundamental_from_params(fa, fb, ang, t, (W - 1) / 2, (H - 1) / 2),
               rng.uniform(3, 10, size=2), rng.uniform(3, 10, size=2), rng.normal(0, 0.3, size=(2, 3)), rng.normal(size=(2, 3)))
