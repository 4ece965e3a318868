"""Training: the loop lowers the loss, checkpoints round-trip and resume, NaN stops cleanly,
recipes are validated key by key, the CLI command runs."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_util import synthetic_recipe

from fviz.errors import FvizError
from fviz.models import FNet
from fviz.train.checkpoint import (
    export_weights,
    load_into,
    load_model,
    read_checkpoint,
    save_checkpoint,
)
from fviz.train.data import TensorPairs
from fviz.train.loop import TrainingDiverged, train
from fviz.train.losses import f_loss, sample_points_on_geometry
from fviz.train.runtime import epoch_batches
from fviz.train.splits import synthetic_seeds
from fviz.train.recipe import Recipe, load_recipe

PROJECT = Path(__file__).resolve().parents[1]


pytestmark = pytest.mark.usefixtures("torch_one_thread")


TINY_MODEL = {"input_size": [32, 96], "width": 8, "hidden": 16, "pool_grid": [2, 4], "dropout": 0.0}


def _synthetic_available() -> bool:
    try:
        from fviz.data.synthetic import SceneConfig, render_batch  # noqa: F401
    except ImportError:
        return False
    return True


def _recipe(tmp_path: Path, variant: str = "siamese-rec-pos-fbn", **train) -> Recipe:
    t = {"batch_size": 4, "lr": 1e-3, "epochs": 1, "num_workers": 0, "out_dir": str(tmp_path / "run"), "seed": 0,
         "loss_frame": "conditioned", **train}
    return Recipe.from_dict({
        "model": {"variant": variant, **TINY_MODEL},
        "data": {"source": "synthetic", "train_size": 8, "val_size": 4, "val_points": 32},
        "train": t,
    })


def curve_steps(path: Path, entity: str) -> list[int]:
    """The ``step`` values of one curve in a training recording, read back with Rerun's RrdReader."""
    from fviz.record.reader import _chunks, _index_names, _ints

    steps = []
    for ent, _, rb in _chunks(path):
        if ent == entity and "step" in _index_names(rb):
            steps += _ints(rb.column("step"))
    return sorted(steps)


def _tiny_pairs(n: int, norm: str = "fbn", seed: int = 0) -> TensorPairs:
    """Deterministic stand-in data: random images, F from random forward motions (exact, normalized)."""
    from fviz.geometry import fundamental_from_motion, normalize

    g = np.random.default_rng(seed)
    H, W = TINY_MODEL["input_size"]
    K = np.array([[0.6 * W, 0, (W - 1) / 2], [0, 0.6 * W, (H - 1) / 2], [0, 0, 1]])
    Fs = []
    for _ in range(n):
        a = g.normal(0, 0.05, 3)
        R = np.array([[1, -a[2], a[1]], [a[2], 1, -a[0]], [-a[1], a[0], 1]])
        U, _, Vt = np.linalg.svd(R)
        Fs.append(normalize(fundamental_from_motion(K, K, U @ Vt, np.array([g.normal(0, 0.3), g.normal(0, 0.1), -1.0])), norm))
    imgs = torch.from_numpy(g.random((2, n, 1, H, W)).astype(np.float32))
    return TensorPairs(imgs[0], imgs[1], torch.from_numpy(np.stack(Fs)).float())


def _data(recipe: Recipe):
    """The real synthetic source when it exists, else the stand-in (never a substitute for it)."""
    if _synthetic_available():
        return None
    return _tiny_pairs(8), _tiny_pairs(4, seed=1)


# ----------------------------------------------------------------------------------------------- the loop


def test_a_few_steps_lower_the_loss(tmp_path):
    recipe = _recipe(tmp_path, epochs=8, val_every=0)  # 8 pairs, 2 steps per epoch: 16 steps, memorizing
    res = train(recipe, datasets=_data(recipe), record=False)
    assert res.step == 16 and len(res.losses) == 16
    first, last = np.mean(res.losses[:4]), np.mean(res.losses[-4:])
    assert last < 0.7 * first, res.losses
    assert [h["step"] for h in res.history] == [2 * i for i in range(1, 9)]
    for key in ("loss", "epi_abs", "epi_sqr", "sed_px", "f_dist"):
        assert math.isfinite(res.metrics[key]), key
    assert res.weights is not None and res.weights.is_file() and res.checkpoint.is_file()


def _etr_pairs(n: int, seed: int = 0) -> TensorPairs:
    """Targets where ETR is defined: sideways (stereo-like) motions whose F33 carries most of ||F|| in input pixels,
    as in KITTI's unrectified cameras (forward motion has F33 ~ 0, where ETR's sign is a coin toss), ETR-normalized."""
    from fviz.geometry import fundamental_from_motion, normalize

    g = np.random.default_rng(seed)
    H, W = TINY_MODEL["input_size"]
    K = np.array([[0.6 * W, 0, (W - 1) / 2], [0, 0.6 * W, (H - 1) / 2], [0, 0, 1]])
    Fs = []
    for _ in range(n):
        a = g.normal(0, 0.05, 3)
        a[0] = 0.1 + abs(a[0])  # a tilt about x: the rows of a and b differ, F33 != 0
        U, _, Vt = np.linalg.svd(np.array([[1, -a[2], a[1]], [a[2], 1, -a[0]], [-a[1], a[0], 1]]))
        F = fundamental_from_motion(K, K, U @ Vt, np.array([-1.0, g.normal(0, 0.1), g.normal(0, 0.1)]))
        assert abs(normalize(F, "fbn")[2, 2]) > 0.5
        Fs.append(normalize(F, "etr"))
    imgs = torch.from_numpy(g.random((2, n, 1, H, W)).astype(np.float32))
    return TensorPairs(imgs[0], imgs[1], torch.from_numpy(np.stack(Fs)).float())


@pytest.mark.parametrize("head", ["base", "rec", "epi"])
@pytest.mark.parametrize("norm", ["etr", "fbn", "abs"])
def test_every_head_and_norm_trains(tmp_path, head, norm):
    """8 steps on one fixed batch of 4 pairs (the training set is that batch): the loss falls by more than 15 %
    for every head and normalization (measured: to 1-71 % of its start), and validation gives finite figures."""
    arch, pos = ("single", False) if norm == "abs" else ("siamese", norm == "etr")
    variant = f"{arch}-{head}{'-pos' if pos else ''}-{norm}"
    recipe = _recipe(tmp_path, variant=variant, max_steps=8, epochs=8, val_every=0)
    data = (_etr_pairs(4), _etr_pairs(4, seed=1)) if norm == "etr" else (_tiny_pairs(4, norm), _tiny_pairs(4, norm, seed=1))
    res = train(recipe, datasets=data, record=False, held_out=False)
    assert res.step == 8 and all(math.isfinite(v) for v in res.losses)
    first, last = np.mean(res.losses[:2]), np.mean(res.losses[-2:])
    assert last < 0.85 * first, (variant, res.losses)
    assert math.isfinite(res.metrics["sed_px"]) and math.isfinite(res.metrics["ahead_sed_px"])


def test_checkpoint_round_trip_same_outputs(tmp_path):
    torch.manual_seed(0)
    model = FNet.from_variant("siamese-epi-pos-abs", input_hw=(32, 96), width=8, hidden=16, pool_grid=(2, 4))
    opt = torch.optim.Adam(model.parameters(), 1e-3)
    a, b = torch.rand(2, 1, 32, 96), torch.rand(2, 1, 32, 96)
    model(a, b).sum().backward()
    opt.step()  # running BN stats and optimizer state are non-trivial
    model.eval()
    path = save_checkpoint(tmp_path / "ck.pt", model, optimizer=opt, step=7, epoch=1, metrics={"last": {"loss": 0.5}})
    loaded, meta = load_model(path)
    with torch.no_grad():
        assert torch.equal(model(a, b), loaded(a, b))
    assert meta["variant"] == "siamese-epi-pos-abs" and meta["step"] == 7 and meta["code_version"]["fviz"]
    assert not loaded.training
    half = export_weights(path, tmp_path / "w.pt", "float16")
    small, _ = load_model(half)
    with torch.no_grad():
        assert torch.allclose(model(a, b), small(a, b), atol=2e-2)
    assert half.stat().st_size < 0.6 * path.stat().st_size  # no optimizer state, half precision
    assert read_checkpoint(half)["optimizer_state"] is None


def test_training_outputs_load_and_agree(tmp_path):
    recipe = _recipe(tmp_path, max_steps=3, epochs=2)
    res = train(recipe, datasets=_data(recipe), record=False)
    full, meta = load_model(res.checkpoint)
    shipped, _ = load_model(res.weights)
    assert meta["recipe"]["model"]["variant"] == "siamese-rec-pos-fbn" and meta["step"] == 3
    assert "history" in meta["metrics"] and meta["metrics"]["last"] == res.metrics
    a, b = torch.rand(1, 1, 32, 96), torch.rand(1, 1, 32, 96)
    with torch.no_grad():
        assert torch.allclose(full(a, b), shipped(a, b), atol=2e-2)


def test_resume_continues_the_step_count(tmp_path):
    recipe = _recipe(tmp_path, max_steps=3, epochs=5, log_every=1)
    data = _data(recipe)
    first = train(recipe, datasets=data, record=True)
    assert first.step == 3 and first.recording.name == "train.rrd" and first.recording.is_file()
    with pytest.raises(FvizError, match="already holds a checkpoint"):
        train(recipe, datasets=data, record=False)
    recipe.train.max_steps = 7
    second = train(recipe, datasets=data, resume=True, record=True)
    assert second.step == 7 and len(second.losses) == 4
    assert read_checkpoint(second.checkpoint)["step"] == 7
    assert second.recording == first.recording  # one train.rrd, rewritten complete with the whole history
    assert curve_steps(second.recording, "train/loss") == list(range(1, 8))
    assert not list(second.out_dir.glob("*.part")) and not list(second.out_dir.glob(".*tmp*"))
    assert second.history[0]["step"] == first.history[0]["step"]  # history carried over
    # the resumed run follows the same batches as an uninterrupted one
    recipe2 = _recipe(tmp_path / "straight", max_steps=7, epochs=5)
    straight = train(recipe2, datasets=data, record=False)
    np.testing.assert_allclose(first.losses + second.losses, straight.losses, rtol=1e-4, atol=1e-6)


def test_resume_without_checkpoint_is_an_error(tmp_path):
    recipe = _recipe(tmp_path)
    with pytest.raises(FvizError, match="no checkpoint to resume"):
        train(recipe, datasets=_tiny_pairs(8), resume=True, record=False)


class _NaNAfter(TensorPairs):
    """Gives NaN targets from the ``after``-th batch on."""

    def __init__(self, base: TensorPairs, after: int):
        super().__init__(base.img_a, base.img_b, base.F)
        self.after, self.calls = after, 0

    def __getitem__(self, idx):
        a, b, F = super().__getitem__(idx)
        self.calls += 1
        return (a, b, F * float("nan")) if self.calls > self.after else (a, b, F)


def test_nan_loss_stops_and_keeps_the_last_good_checkpoint(tmp_path):
    recipe = _recipe(tmp_path, epochs=10, checkpoint_every=2, val_every=0)
    recipe.train.batch_size = 2
    # 7 good reads: the REC head's translation rescaling and the training mean F's reference (the first pair) read
    # one each before the first step, then steps 1-5
    data = (_NaNAfter(_tiny_pairs(8), after=7), _tiny_pairs(2, seed=1))
    with pytest.raises(TrainingDiverged, match=r"loss became nan at step 6 .*last good checkpoint .*step 4") as info:
        train(recipe, datasets=data, record=True)
    assert isinstance(info.value, FvizError) and info.value.step == 6
    model, meta = load_model(info.value.checkpoint)
    assert meta["step"] == 4
    assert all(torch.isfinite(p).all() for p in model.state_dict().values() if p.is_floating_point())
    assert (tmp_path / "run" / "train.rrd").is_file()  # curves up to the stop are kept


@pytest.mark.skipif(not _synthetic_available(), reason="fviz.data.synthetic not importable")
def test_cached_data_trains_exactly_like_rendering(tmp_path):
    plain = train(_recipe(tmp_path / "a", max_steps=3, epochs=2), record=False)
    cached_recipe = _recipe(tmp_path / "b", max_steps=3, epochs=2)
    cached_recipe.data.cache = True
    cached = train(cached_recipe, record=False)
    np.testing.assert_allclose(plain.losses, cached.losses, rtol=1e-5)  # synthetic images are exact uint8 levels
    assert plain.metrics == pytest.approx(cached.metrics, rel=1e-4)


def test_learning_rate_schedule():
    from fviz.train.loop import lr_at
    from fviz.train.recipe import TrainSection

    t = TrainSection(lr=1.0, warmup_steps=10, schedule="cosine")
    assert lr_at(0, 110, t) == pytest.approx(0.1) and lr_at(9, 110, t) == pytest.approx(1.0)
    assert lr_at(10, 110, t) == pytest.approx(1.0) and lr_at(60, 110, t) == pytest.approx(0.5)
    assert lr_at(110, 110, t) == pytest.approx(0.0, abs=1e-12)
    assert lr_at(50, 110, TrainSection(lr=0.3)) == 0.3


def test_loss_is_sign_invariant_except_etr_in_pixels():
    F = torch.randn(3, 3, 3)
    for norm in ("fbn", "abs"):
        assert float(f_loss(F, -F, norm)) == pytest.approx(0.0)
    assert float(f_loss(F, -F, "etr")) > 0  # the paper's literal loss: F / F33 fixed the sign
    assert float(f_loss(F, -F, "etr", frame="conditioned", input_hw=(32, 96))) == pytest.approx(0.0, abs=1e-6)
    cond = f_loss(F, F * 1.0, "fbn", frame="conditioned", input_hw=(32, 96))
    assert float(cond) == pytest.approx(0.0, abs=1e-6)


def test_validation_points_lie_on_the_ground_truth_geometry():
    F = _tiny_pairs(3).F
    xa, xb = sample_points_on_geometry(F, (32, 96), 50, torch.Generator().manual_seed(0))
    r = torch.einsum("bni,bij,bnj->bn", xb, F.double(), xa)
    assert r.abs().max() < 1e-9


def test_epoch_batches_are_deterministic_and_split_across_ranks():
    assert epoch_batches(10, 3, 0, 0) == epoch_batches(10, 3, 0, 0) != epoch_batches(10, 3, 0, 1)
    assert all(len(b) == 3 for b in epoch_batches(10, 3, 0, 0))
    r0, r1 = epoch_batches(11, 2, 0, 0, 0, 2), epoch_batches(11, 2, 0, 0, 1, 2)
    assert len(r0) == len(r1) and not {i for b in r0 for i in b} & {i for b in r1 for i in b}
    tr, va = synthetic_seeds(3, 100, 10)
    assert not set(tr) & set(va)


@pytest.mark.skipif(not _synthetic_available(), reason="fviz.data.synthetic not importable")
def test_synthetic_dataset_targets_match_the_renderer():
    from fviz.data.synthetic import SceneConfig, render_batch
    from fviz.train.splits import make_datasets

    recipe = _recipe(Path("/nonexistent"), variant="single-base-abs")
    train_ds, _ = make_datasets(recipe)
    a, b, F = train_ds[[0, 1]]
    assert a.shape == (2, 1, 32, 96) and b.shape == (2, 1, 32, 96) and F.shape == (2, 3, 3)
    ref = render_batch([train_ds.seeds[0]], SceneConfig(width=96, height=32))
    from fviz.geometry import normalize

    np.testing.assert_allclose(F[0].numpy(), normalize(ref["F"][0].numpy(), "abs"), atol=1e-6)
    assert torch.equal(a[0], ref["image_a"][0].float())


@pytest.mark.kitti
def test_kitti_odometry_pairs_at_the_input_size(kitti_root):
    from fviz.data.kitti import open_dataset
    from fviz.geometry import normalize
    from fviz.models.predict import f_to_input
    from fviz.train.splits import make_datasets

    recipe = Recipe.from_dict({
        "model": {"variant": "siamese-rec-pos-fbn", **TINY_MODEL},
        "data": {"source": "kitti-odometry", "root": str(kitti_root), "sequences": ["00"], "frames": [0, 12],
                 "steps": [1, 2], "val_fraction": 0.25},
    })
    train_ds, val_ds = make_datasets(recipe)
    assert len(train_ds) + len(val_ds) == 11 + 10
    assert max(i.frame for i in train_ds.items) < min(i.frame for i in val_ds.items) + 2  # tail split
    a, _, F = train_ds[[0]]
    assert a.shape == (1, 1, 32, 96) and 0 <= float(a.min()) and float(a.max()) <= 1
    pair = open_dataset(kitti_root, sequence="00").pair(0, kind="temporal", step=1, cams=(0, 0))
    expected = normalize(f_to_input(pair.F_gt, pair.size_a, pair.size_b, (32, 96)), "fbn")
    np.testing.assert_allclose(F[0].numpy(), expected, atol=1e-6)
    recipe.model.variant = "siamese-rec-pos-etr"
    recipe.data.kind = "stereo"
    with pytest.raises(FvizError, match="ETR normalization is undefined for rectified stereo"):
        make_datasets(recipe)


# ----------------------------------------------------------------------------------------------- checkpoints


def test_loading_another_variant_is_a_clear_error(tmp_path):
    model = FNet.from_variant("siamese-rec-pos-fbn", input_hw=(32, 96), width=8, hidden=16, pool_grid=(2, 4))
    path = save_checkpoint(tmp_path / "ck.pt", model)
    other = FNet.from_variant("single-epi-abs", input_hw=(32, 96), width=8, hidden=16, pool_grid=(2, 4))
    with pytest.raises(FvizError, match="holds variant 'siamese-rec-pos-fbn'.*'single-epi-abs' model"):
        load_into(other, path)
    wider = FNet.from_variant("siamese-rec-pos-fbn", input_hw=(32, 96), width=16, hidden=16, pool_grid=(2, 4))
    with pytest.raises(FvizError, match="model width is 8 in the checkpoint but 16"):
        load_into(wider, path)


def test_foreign_files_are_not_checkpoints(tmp_path):
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"definitely not a torch file")
    with pytest.raises(FvizError, match="not an fviz model checkpoint"):
        load_model(junk)
    plain = tmp_path / "plain.pt"
    torch.save({"weights": torch.zeros(3)}, plain)
    with pytest.raises(FvizError, match="not an fviz model checkpoint"):
        load_model(plain)
    with pytest.raises(FvizError, match="checkpoint not found"):
        load_model(tmp_path / "missing.pt")


# ----------------------------------------------------------------------------------------------- recipes


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_recipe_unknown_key_names_file_and_key(tmp_path):
    p = _write(tmp_path / "x.toml", '[model]\nhed = "rec"\n')
    with pytest.raises(FvizError, match=r"recipe .*x\.toml: unknown key 'model\.hed'"):
        load_recipe(p)
    p = _write(tmp_path / "y.toml", "[optim]\nlr = 1\n")
    with pytest.raises(FvizError, match=r"y\.toml: unknown key 'optim'"):
        load_recipe(p)


def test_recipe_wrong_type_names_the_key(tmp_path):
    p = _write(tmp_path / "x.toml", '[train]\nlr = "fast"\n')
    with pytest.raises(FvizError, match=r"x\.toml: train\.lr must be a float, got 'fast'"):
        load_recipe(p)
    p = _write(tmp_path / "y.toml", "[train]\nbatch_size = 2.5\n")
    with pytest.raises(FvizError, match=r"train\.batch_size must be an int"):
        load_recipe(p)
    p = _write(tmp_path / "z.toml", '[data]\nsource = "imagenet"\n')
    with pytest.raises(FvizError, match=r"data\.source must be one of"):
        load_recipe(p)
    p = _write(tmp_path / "v.toml", '[model]\nvariant = "siamese-rec-l2"\n')
    with pytest.raises(FvizError, match="unknown model variant"):
        load_recipe(p)
    p = _write(tmp_path / "bad.toml", "[train\n")
    with pytest.raises(FvizError, match="invalid TOML"):
        load_recipe(p)


def test_set_overrides_are_validated_the_same_way(tmp_path):
    p = _write(tmp_path / "x.toml", "[train]\nlr = 1e-4\n")
    r = load_recipe(p, ["train.lr=3e-4", "model.variant=single-epi-abs", "model.input_size=[64, 208]", "data.synthetic.noise_sigma=2"])
    assert r.train.lr == 3e-4 and r.model.variant == "single-epi-abs" and r.input_hw == (64, 208)
    assert r.data.synthetic == {"noise_sigma": 2}
    with pytest.raises(FvizError, match=r"--set model\.hed=3: unknown key 'model\.hed'"):
        load_recipe(p, ["model.hed=3"])
    with pytest.raises(FvizError, match=r"--set train\.epochs=many: train\.epochs must be an int"):
        load_recipe(p, ["train.epochs=many"])
    with pytest.raises(FvizError, match="expected KEY=VALUE"):
        load_recipe(p, ["train.epochs"])


def test_base_recipe_and_variant_overrides(tmp_path):
    _write(tmp_path / "base.toml", """
[model]
variant = "siamese-rec-pos-fbn"
[train]
lr = 1e-4
epochs = 3
[variants."single-base-etr"]
train = { lr = 5e-5 }
""")
    child = _write(tmp_path / "child.toml", 'base = "base.toml"\n[train]\nepochs = 7\n')
    r = load_recipe(child)
    assert (r.model.variant, r.train.lr, r.train.epochs) == ("siamese-rec-pos-fbn", 1e-4, 7)
    r = load_recipe(child, ["model.variant=single-base-etr"])
    assert (r.train.lr, r.train.epochs) == (5e-5, 7)  # the variant's table applies
    r = load_recipe(child, ["model.variant=single-base-etr", "train.lr=1e-3"])
    assert r.train.lr == 1e-3  # --set wins over everything
    _write(tmp_path / "bad.toml", '[variants."single-base-etr"]\ntrain = { lrr = 1 }\n')
    with pytest.raises(FvizError, match=r"unknown key 'train\.lrr'"):
        load_recipe(tmp_path / "bad.toml")
    _write(tmp_path / "loop.toml", 'base = "loop.toml"\n')
    with pytest.raises(FvizError, match="loops back"):
        load_recipe(tmp_path / "loop.toml")


def test_recipe_round_trips_through_a_dict(tmp_path):
    r = load_recipe(PROJECT / "recipes" / "synthetic_small.toml")
    again = Recipe.from_dict(r.to_dict())
    assert again.to_dict() == r.to_dict()


def test_bundled_recipes_are_valid():
    from fviz.models import VARIANTS

    for name in ("synthetic_small.toml", "synthetic_bundled.toml", "kitti_base.toml"):
        r = load_recipe(PROJECT / "recipes" / name)
        net = r.fnet_config()
        assert net.variant == r.model.variant
    per_variant = sorted((PROJECT / "recipes" / "kitti").glob("*.toml"))
    assert sorted(p.stem for p in per_variant) == sorted(VARIANTS)
    for p in per_variant:
        r = load_recipe(p)
        assert r.model.variant == p.stem and r.data.source == "kitti-odometry"
        assert p.stem in r.train.out_dir or "{variant}" in r.train.out_dir
    bundled = load_recipe(PROJECT / "recipes" / "synthetic_bundled.toml")
    n = sum(p.numel() for p in FNet.from_config(bundled.fnet_config()).parameters())
    assert n * 2 < 20e6 and n * 4 < 20e6  # float16 (exported) and even float32 fit


# ----------------------------------------------------------------------------------------------- CLI


def test_cli_train_command(tmp_path, monkeypatch):
    import typer
    from typer.testing import CliRunner

    from fviz.cli.train import register

    app = typer.Typer()
    register(app)

    @app.command("noop")
    def noop() -> None:  # a second command keeps "train" a subcommand
        pass

    recipe = synthetic_recipe(tmp_path / "r.toml", tmp_path / "out" / "{variant}")
    if not _synthetic_available():
        pytest.skip("fviz.data.synthetic not importable")
    runner = CliRunner()
    res = runner.invoke(app, ["train", str(recipe), "--set", "train.max_steps=2"])
    assert res.exit_code == 0, res.output
    # the end of training sets the model beside both constants, in one line (2 steps: no better than them)
    end = " ".join(res.output.split("done:", 1)[1].split())  # what follows the last step, unwrapped
    assert re.search(r"the model is no better than the constant: validation median SED [\d.]+ px vs [\d.]+ px for the "
                     r"training pairs' mean F \(p [\d.e-]+\) and [\d.]+ px for straight-ahead motion", end), res.output
    assert (tmp_path / "out" / "siamese-rec-pos-fbn" / "model.pt").is_file()
    res = runner.invoke(app, ["train", str(recipe), "--set", "train.max_steps=3", "--resume"])
    assert res.exit_code == 0, res.output
    assert read_checkpoint(tmp_path / "out" / "siamese-rec-pos-fbn" / "last.pt")["step"] == 3
    res = runner.invoke(app, ["train", str(recipe), "--set", "model.hed=1"])
    assert isinstance(res.exception, FvizError) and "unknown key 'model.hed'" in str(res.exception)


def test_init_starts_from_another_models_weights(tmp_path):
    """train.init (synthetic pretraining, then fine-tuning): with lr = 0 the run's weights are the init's;
    another architecture is refused naming train.init."""
    torch.manual_seed(3)
    start = FNet.from_variant("siamese-rec-pos-fbn", input_hw=(32, 96), width=8, hidden=16, pool_grid=(2, 4), dropout=0.0)
    init = save_checkpoint(tmp_path / "pretrained.pt", start)
    recipe = _recipe(tmp_path, max_steps=2, lr=0.0, init=str(init), t_norm_weight=0.0)  # no translation rescaling
    res = train(recipe, datasets=_data(recipe), record=False)
    tuned, _ = load_model(res.checkpoint)
    for k, v in start.state_dict().items():
        if v.is_floating_point() and "running" not in k:  # BatchNorm statistics follow the batches
            torch.testing.assert_close(tuned.state_dict()[k], v)
    other = _recipe(tmp_path / "other", max_steps=1, init=str(init))
    other.model.width = 16
    with pytest.raises(FvizError, match="train.init .*pretrained.pt: model width is 8 in the checkpoint but 16"):
        train(other, datasets=_data(other), record=False)
