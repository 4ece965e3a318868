"""The paper's networks: every variant's shape, rank and normalization; heads against closed forms;
torch normalization against numpy; gradients; the coordinate mapping of predict_F."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from fviz.errors import FvizError
from fviz.geometry import (
    NormalizationError,
    f_distance,
    fundamental_from_motion,
    normalize,
)
from fviz.models import (
    VARIANTS,
    FNet,
    FNetConfig,
    count_parameters,
    parse_variant,
    predict_F,
    variant_name,
)
from fviz.models.heads import RecHead, euler_to_rotation, fundamental_from_params
from fviz.models.normalization import ETR_TRAIN_EPS, normalize_f
from fviz.models.predict import f_to_full, f_to_input, scale_matrix, to_model_input

pytestmark = pytest.mark.usefixtures("torch_one_thread")


SMALL = dict(input_hw=(24, 64), width=8, hidden=16, pool_grid=(2, 3), ucn_channels=(4, 8, 8), dropout=0.0)


def _images(B: int, hw=(24, 64), seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(B, 1, *hw, generator=g), torch.rand(B, 1, *hw, generator=g)


def _rot_np(rx: float, ry: float, rz: float) -> np.ndarray:
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rx @ Ry @ Rz


def test_variants_are_the_papers_36():
    assert len(VARIANTS) == len(set(VARIANTS)) == 36
    assert "siamese-rec-pos-fbn" in VARIANTS and "single-base-etr" in VARIANTS and "single-epi-pos-abs" in VARIANTS
    for name in VARIANTS:
        assert variant_name(**parse_variant(name)) == name
    heads = {(v["head"], v["pos"]) for v in map(parse_variant, VARIANTS)}
    assert len(heads) == 6  # Base, POS, EPI, EPI+POS, REC, REC+POS
    for bad in ("siamese-rec-fbn-pos-x", "double-rec-fbn", "siamese-foo-fbn", "siamese-rec-l2"):
        with pytest.raises(FvizError, match="unknown model variant"):
            parse_variant(bad)


@pytest.mark.parametrize("name", VARIANTS)
def test_every_variant_shape_rank_and_normalization(name):
    torch.manual_seed(0)
    model = FNet.from_variant(name, **SMALL)
    a, b = _images(3)
    F_train = model(a, b)  # train mode: non-strict normalization
    model.eval()
    with torch.no_grad():
        F = model(a, b)
    for out in (F_train, F):
        assert out.shape == (3, 3, 3) and out.dtype == torch.float32 and torch.isfinite(out).all()
    v = parse_variant(name)
    F64 = F.double()
    if v["head"] in ("rec", "epi"):
        s = torch.linalg.svdvals(F64)
        assert (s[:, 2] / s[:, 0]).max() < 1e-5, f"{name}: not rank 2: {s}"
    flat = F64.flatten(1)
    if v["norm"] == "fbn":
        assert torch.allclose(flat.norm(dim=1), torch.ones(3, dtype=torch.float64), atol=1e-5)
        assert (flat.gather(1, flat.abs().argmax(1, keepdim=True)) > 0).all()
    elif v["norm"] == "abs":
        assert torch.allclose(flat.abs().max(dim=1).values, torch.ones(3, dtype=torch.float64), atol=1e-6)
    else:
        assert torch.allclose(F64[:, 2, 2], torch.ones(3, dtype=torch.float64), atol=1e-6)


@pytest.mark.parametrize("arch", ["siamese", "single"])
def test_indexed_pairs_equal_the_pairs_run_apart(arch):
    """FNet.indexed runs each image's stream once for every pair it is in (a pair and its reverse share them)."""
    torch.manual_seed(0)
    model = FNet.from_variant(f"{arch}-rec-pos-fbn", **SMALL).eval()
    a, b = _images(2, seed=1)
    images, index = torch.cat([a, b]), torch.tensor([[0, 2], [1, 3], [2, 0], [3, 1], [0, 3]])
    with torch.no_grad():
        apart = model(images[index[:, 0]], images[index[:, 1]])
        got = model.indexed(images, index)
    torch.testing.assert_close(got, apart, rtol=0, atol=1e-6)
    assert (got[0] - got[2]).abs().max() > 1e-4  # (a, b) and (b, a) differ: the index is followed


def test_every_variant_fits_20_mb_at_the_default_size():
    for name in VARIANTS:
        if not name.endswith("-fbn"):  # the norm has no weights: 12 distinct sizes
            continue
        n = count_parameters(FNet.from_variant(name))
        assert n * 4 < 20e6, f"{name}: {n} parameters = {n * 4 / 1e6:.1f} MB in float32"


def test_wrong_input_size_is_a_clear_error():
    model = FNet.from_variant("siamese-rec-pos-fbn", **SMALL)
    a, b = _images(1, (24, 60))
    with pytest.raises(FvizError, match=r"must be \(B, 1, 24, 64\)"):
        model(a, b)


def test_config_round_trip():
    model = FNet.from_variant("single-epi-pos-abs", **SMALL)
    cfg = FNetConfig.from_dict(model.config.to_dict())
    assert cfg == model.config and cfg.variant == "single-epi-pos-abs"
    with pytest.raises(FvizError, match="unknown field"):
        FNetConfig.from_dict({**model.config.to_dict(), "depth": 3})


# ----------------------------------------------------------------------------------------------- normalization


@pytest.mark.parametrize("norm", ["etr", "fbn", "abs"])
def test_torch_normalization_equals_numpy(norm):
    rng = np.random.default_rng(1)
    F = rng.normal(size=(50, 3, 3)) * 10 ** rng.uniform(-4, 2, size=(50, 1, 1))
    F[:5] *= -1
    expected = normalize(F, norm)
    got64 = normalize_f(torch.from_numpy(F), norm).numpy()
    np.testing.assert_allclose(got64, expected, rtol=1e-12, atol=1e-12)
    got32 = normalize_f(torch.from_numpy(F).float(), norm).double().numpy()
    np.testing.assert_allclose(got32, expected, rtol=1e-5, atol=1e-6)
    layer = FNet.from_variant(f"siamese-rec-{norm}", **SMALL).norm.eval()  # the layer inside the model
    np.testing.assert_allclose(layer(torch.from_numpy(F)).numpy(), expected, rtol=1e-12, atol=1e-12)


def test_etr_guard_strict_raises_training_clamps():
    F = torch.tensor([[[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]], dtype=torch.float64)  # rectified stereo
    with pytest.raises(NormalizationError, match="F33"):
        normalize_f(F, "etr", strict=True)
    with pytest.raises(NormalizationError):
        normalize(F.numpy(), "etr")  # the numpy side agrees
    out = normalize_f(F, "etr", strict=False)
    assert torch.isfinite(out).all()
    assert out.abs().max() == pytest.approx(1 / (ETR_TRAIN_EPS * np.sqrt(2)), rel=1e-9)
    G_neg, G_pos = F.clone(), F.clone()
    G_neg[0, 2, 2], G_pos[0, 2, 2] = -1e-9, 1e-9
    out_neg, out_pos = normalize_f(G_neg, "etr", strict=False), normalize_f(G_pos, "etr", strict=False)
    assert out_neg[0, 2, 2] > 0 and out_pos[0, 2, 2] > 0  # the clamp keeps the sign of F33: ETR's F33 stays positive
    assert torch.allclose(out_neg[0, :2], -out_pos[0, :2])
    layer = FNet.from_variant("single-base-etr", **SMALL).norm
    layer.train()
    assert torch.isfinite(layer(F)).all()  # training mode: clamps
    layer.eval()
    with pytest.raises(FvizError):
        layer(F)  # inference: a clear one-line error


# ----------------------------------------------------------------------------------------------- heads


def test_rec_layer_equals_fundamental_from_motion():
    rng = np.random.default_rng(2)
    H, W = 24, 64
    cx, cy = (W - 1) / 2, (H - 1) / 2
    for _ in range(5):
        f_a, f_b = rng.uniform(20, 200, size=2)
        ang = rng.normal(0, 0.3, size=3)
        t = rng.normal(size=3)
        K_a = np.array([[f_a, 0, cx], [0, f_a, cy], [0, 0, 1]])
        K_b = np.array([[f_b, 0, cx], [0, f_b, cy], [0, 0, 1]])
        expected = fundamental_from_motion(K_a, K_b, _rot_np(*ang), t)
        got = fundamental_from_params(
            torch.tensor([f_a]), torch.tensor([f_b]), torch.from_numpy(ang[None]), torch.from_numpy(t[None]), cx, cy
        )[0].numpy()
        np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(euler_to_rotation(torch.tensor(ang)).numpy(), _rot_np(*ang), atol=1e-12)
        # and through the head's output units: f = max(H, W) exp(2 tanh(raw / 2)), angles = 0.1 raw, t = raw / |raw|
        head = RecHead(4, (H, W))
        raw_f = [2 * np.arctanh(np.log(f / W) / 2) for f in (f_a, f_b)]
        raw = torch.tensor([[*raw_f, *(ang / 0.1), *(3.0 * t)]])
        unit = fundamental_from_motion(K_a, K_b, _rot_np(*ang), t / np.linalg.norm(t))
        np.testing.assert_allclose(head.to_fundamental(raw)[0].numpy(), unit, rtol=1e-9, atol=1e-14)


def test_epi_head_epipole_is_alpha_beta():
    model = FNet.from_variant("single-epi-fbn", **{**SMALL, "conditioned": False})
    head = model.head
    y = torch.tensor([[1.0, 2.0, 0.5, -1.0, 0.3, 2.0, 7.0, -3.0]], dtype=torch.float64)
    F = head.to_fundamental(y)[0]
    e_a = torch.tensor([7.0, -3.0, -1.0], dtype=torch.float64)
    assert torch.allclose(F @ e_a, torch.zeros(3, dtype=torch.float64), atol=1e-12)


@pytest.mark.parametrize("head", ["base", "rec", "epi"])
@pytest.mark.parametrize("arch", ["single", "siamese"])
def test_gradients_reach_every_parameter(arch, head):
    torch.manual_seed(0)
    model = FNet(arch, head, True, "fbn", **SMALL)
    a, b = _images(4, seed=3)
    target = normalize_f(torch.randn(4, 3, 3), "fbn")
    loss = (model(a, b) - target).square().mean()
    loss.backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, f"{arch}-{head}: no gradient reaches {name}"


def test_position_features_are_normalized_argmax_positions():
    from fviz.models.pooling import LocationAwarePool

    x = torch.zeros(1, 2, 6, 9)
    x[0, 0, 4, 7] = 5.0  # one clear maximum per channel in a single window
    x[0, 1, 1, 2] = 3.0
    out = LocationAwarePool((1, 1), pos=True)(x)
    assert out.shape == (1, 6, 1, 1)
    values, rows, cols = out[0, :2, 0, 0], out[0, 2:4, 0, 0], out[0, 4:6, 0, 0]
    assert values.tolist() == [5.0, 3.0]
    assert rows.tolist() == pytest.approx([4 / 5, 1 / 5])
    assert cols.tolist() == pytest.approx([7 / 8, 2 / 8])
    assert LocationAwarePool((3, 10), pos=False)(torch.rand(2, 4, 30, 50)).shape == (2, 4, 3, 10)


# ----------------------------------------------------------------------------------------------- predict_F


def test_scale_matrix_follows_opencv_pixel_centres():
    H, W, h, w = 120, 400, 30, 100
    yy, xx = np.mgrid[0:H, 0:W]
    x0, y0 = 173.3, 61.7
    img = np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2) / (2 * 6.0**2))
    small = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    ys, xs = np.mgrid[0:h, 0:w]
    centroid = np.array([(small * xs).sum(), (small * ys).sum()]) / small.sum()
    expected = (scale_matrix((W, H), (w, h)) @ [x0, y0, 1.0])[:2]
    np.testing.assert_allclose(centroid, expected, atol=0.02)


class _FixedF(torch.nn.Module):
    """A stand-in model that always predicts the same F (in model-input pixels)."""

    def __init__(self, F_small: np.ndarray, input_hw):
        super().__init__()
        self.config = FNetConfig(input_hw=input_hw)
        self.w = torch.nn.Parameter(torch.zeros(()))
        self.F = torch.from_numpy(normalize(F_small, "fbn")).float()

    def forward(self, a, b, strict_norm=None):
        assert a.shape[-2:] == self.config.input_hw and a.max() <= 1.0
        return self.F[None].expand(a.shape[0], 3, 3) + self.w

    def indexed(self, images, index, strict_norm=None):  # FNet's: the pairs (images[i], images[j])
        return self(images[index[:, 0]], images[index[:, 1]], strict_norm)


def test_predict_F_maps_back_to_full_resolution_pixels():
    rng = np.random.default_rng(4)
    size_a, size_b = (1241, 376), (1226, 370)  # (W, H): KITTI-like, two slightly different sizes
    K_a = np.array([[718.0, 0, 607.0], [0, 718.0, 185.0], [0, 0, 1]])
    K_b = np.array([[707.0, 0, 601.0], [0, 707.0, 183.0], [0, 0, 1]])
    R, t = _rot_np(0.01, -0.03, 0.02), np.array([0.2, -0.05, 1.0])
    F_full = fundamental_from_motion(K_a, K_b, R, t)
    X = np.column_stack([rng.uniform(-10, 10, 200), rng.uniform(-3, 3, 200), rng.uniform(5, 40, 200)])
    xa = X @ K_a.T
    xa = xa[:, :2] / xa[:, 2:]
    xb = (X @ R.T + t) @ K_b.T
    xb = xb[:, :2] / xb[:, 2:]
    hw = (96, 320)
    F_small = f_to_input(F_full, size_a, size_b, hw)
    # corresponding points scaled to the model input satisfy F_small
    sa, sb = scale_matrix(size_a, (hw[1], hw[0])), scale_matrix(size_b, (hw[1], hw[0]))
    ha, hb = np.column_stack([xa, np.ones(len(xa))]) @ sa.T, np.column_stack([xb, np.ones(len(xb))]) @ sb.T
    Fs = normalize(F_small, "fbn")
    assert np.abs(np.einsum("ni,ij,nj->n", hb, Fs, ha)).max() < 1e-9
    np.testing.assert_allclose(normalize(f_to_full(F_small, size_a, size_b, hw), "fbn"), normalize(F_full, "fbn"), atol=1e-12)
    # predict_F: resize the images, run the model, map back; the full-resolution points satisfy its F
    img_a = rng.integers(0, 255, size=(size_a[1], size_a[0], 3), dtype=np.uint8)
    img_b = rng.integers(0, 255, size=(size_b[1], size_b[0]), dtype=np.uint8)
    F_pred = predict_F(_FixedF(F_small, hw), img_a, img_b)
    assert F_pred.shape == (3, 3) and F_pred.dtype == np.float64
    assert np.linalg.norm(F_pred) == pytest.approx(1.0)
    assert f_distance(F_pred, F_full) < 1e-6  # float32 model output
    from fviz.geometry import symmetric_epipolar_distance

    assert np.median(symmetric_epipolar_distance(F_pred, xa, xb)) < 0.05


def test_to_model_input_gray_and_range():
    img = np.full((40, 100, 3), 255, np.uint8)
    out = to_model_input(img, (10, 25))
    assert out.shape == (10, 25) and out.dtype == np.float32 and np.allclose(out, 1.0)
    with pytest.raises(FvizError):
        to_model_input(np.zeros((2, 3, 4, 5), np.uint8), (10, 25))


def test_predict_F_with_a_real_model_runs():
    torch.manual_seed(0)
    model = FNet.from_variant("siamese-rec-pos-fbn", **SMALL)
    img = np.random.default_rng(0).integers(0, 255, (375, 1242), dtype=np.uint8)
    F = predict_F(model, img, img)
    assert F.shape == (3, 3) and np.isfinite(F).all() and np.linalg.norm(F) == pytest.approx(1.0)
    assert model.training  # restored
