"""The public Python API (``import fviz``): pairs from arrays, caller-given F, recordings, training steps.

Checked against independent computations (the ground truth's own row, the CLI's JSON, the geometry module)
and read back from the files with Rerun's reader; real KITTI odometry 00 and synthetic scenes."""

import json
import subprocess
import sys

import numpy as np
import pytest
import rerun as rr
from cli_util import run_fviz

import fviz
from fviz import api
from fviz.errors import FvizError
from fviz.geometry import normalize, symmetric_epipolar_distance
from fviz.record import layout as L
from fviz.record import reader as R

SCORED_LIKE_GT = ("sed_mean", "sed_median", "sampson_mean", "sampson_median", "epi_abs", "epi_sqr", "epi_abs_abs",
                  "epi_sqr_etr", "n_inliers", "inlier_ratio", "gt_inlier_ratio", "epipole_err_deg", "nsgd")


@pytest.fixture(scope="module")
def kitti_pair(kitti_root):
    return fviz.load_pair(kitti_root, sequence="00", frame=0, kind="temporal")


@pytest.fixture(scope="module")
def from_arrays(kitti_pair):
    """The same KITTI pair given as two arrays, its cameras and pose (what a user has)."""
    p = kitti_pair
    return fviz.pair_from_images(p.image_a.copy(), p.image_b.copy(), K_a=p.K_a, K_b=p.K_b, R=p.R, t=p.t)


def test_import_fviz_is_light_and_exports_the_api():
    code = ("import sys, fviz; heavy = [m for m in ('numpy', 'torch', 'rerun', 'cv2') if m in sys.modules]; "
            "print(heavy, sorted(fviz.__all__)); fviz.inspect_pair; print('numpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[0].startswith("[] ")  # nothing heavy at import
    assert out[1] == "True"  # the API loads on first use
    from fviz.estimators.registry import DEFAULT_ESTIMATORS

    assert api.DEFAULT_ESTIMATORS == DEFAULT_ESTIMATORS
    from fviz.evaluate import PairResult

    assert fviz.PairResult is PairResult
    with pytest.raises(AttributeError):
        fviz.no_such_name  # noqa: B018


def test_pair_from_arrays_has_the_datasets_ground_truth(kitti_pair, from_arrays):
    assert from_arrays.ground_truth == "pose" and from_arrays.size_a == kitti_pair.size_a
    F, G = from_arrays.F_gt, normalize(kitti_pair.F_gt, "fbn")
    assert min(np.abs(F - G).max(), np.abs(F + G).max()) < 1e-9
    # (C, H, W) floats in [0, 1] (torch's layout) are the same image
    chw = fviz.pair_from_images(kitti_pair.image_a[None] / 255.0, kitti_pair.image_b[None] / 255.0)
    np.testing.assert_array_equal(chw.image_a, kitti_pair.image_a)
    assert chw.ground_truth == "none"


def test_own_F_equal_to_the_ground_truth_scores_as_the_ground_truth(from_arrays):
    result = fviz.inspect_pair(from_arrays, estimators=(), F={"mine": from_arrays.F_gt * -3.0})
    gt, mine = result.get("gt"), result.get("mine")
    assert [r.name for r in result.estimators] == ["gt", "mine"] and mine.error is None
    for k in SCORED_LIKE_GT:
        assert mine.metrics[k] == pytest.approx(gt.metrics[k], rel=1e-9, abs=1e-12), k
    assert mine.metrics["rot_err_deg"] < 1e-3 and mine.metrics["trans_err_deg"] < 1e-3  # its pose, recovered
    # independently: the median SED of F_gt on the matches within 2 px of it
    m = result.matches
    sed = symmetric_epipolar_distance(from_arrays.F_gt, m.x_a, m.x_b)
    assert mine.metrics["sed_median"] == pytest.approx(np.median(sed[sed < 2.0]), rel=1e-12)
    assert result.n_eval == int((sed < 2.0).sum()) > 100


def test_own_F_is_a_row_beside_the_estimators(from_arrays):
    wrong = from_arrays.F_gt + 1e-5 * np.arange(9).reshape(3, 3)
    result = fviz.inspect_pair(from_arrays, estimators=("8point",), F={"mine": wrong})
    assert [r.name for r in result.estimators] == ["gt", "8point", "mine"]
    doc = result.to_dict()
    json.dumps(doc)  # what inspect --json prints
    mine = doc["estimators"][2]
    np.testing.assert_allclose(np.array(mine["F"]), wrong)
    assert mine["metrics"]["sed_median"] > result.get("gt").metrics["sed_median"]


@pytest.mark.parametrize("F, fragment", [
    (np.eye(2), "F['mine']: expected shape (3, 3)"),
    (np.full((3, 3), np.nan), "F['mine']: has NaN"),
    (np.zeros((3, 3)), "F['mine']: all zero"),
])
def test_bad_own_F_is_a_one_line_error_naming_the_key(from_arrays, F, fragment):
    with pytest.raises(FvizError) as exc:
        fviz.inspect_pair(from_arrays, estimators=(), F={"mine": F})
    assert str(exc.value).startswith(fragment) and "\n" not in str(exc.value)


def test_bad_arguments_name_themselves(from_arrays, kitti_pair):
    cases = [
        (lambda: fviz.inspect_pair(from_arrays, estimators=(), F={"gt": np.eye(3)}), "F['gt']"),
        (lambda: fviz.inspect_pair(from_arrays, estimators=("8point",), F={"8point": np.eye(3)}), "F['8point']"),
        (lambda: fviz.inspect_pair("pair.png"), "pair:"),
        (lambda: fviz.pair_from_images(np.zeros((4, 4, 2), np.uint8), kitti_pair.image_b), "image_a:"),
        (lambda: fviz.pair_from_images(kitti_pair.image_a, kitti_pair.image_b, K_a=kitti_pair.K_a), "K_b: missing"),
        (lambda: fviz.pair_from_images(kitti_pair.image_a, kitti_pair.image_b, R=np.eye(3)), "t: missing"),
        (lambda: fviz.pair_from_images(kitti_pair.image_a, kitti_pair.image_b, F_gt=np.ones(3)), "F_gt:"),
    ]
    for call, fragment in cases:
        with pytest.raises(FvizError) as exc:
            call()
        assert fragment in str(exc.value) and "\n" not in str(exc.value), str(exc.value)


def test_load_pair_without_a_root_says_so(monkeypatch):
    monkeypatch.delenv("FVIZ_KITTI_ROOT", raising=False)
    with pytest.raises(FvizError, match="^kitti_root: missing"):
        fviz.load_pair(sequence="00")
    assert fviz.load_pair(synthetic=True, seed=1).ground_truth == "pose"  # no dataset needed


def test_evaluate_is_what_inspect_prints(kitti_root, tmp_path):
    proc = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--frame", "0", "--pair", "temporal",
                    "--estimator", "8point", "--json", "--out", tmp_path / "cli.rrd")
    assert proc.returncode == 0, proc.stderr
    cli = json.loads(proc.stdout)
    doc = fviz.inspect_pair(fviz.load_pair(kitti_root, sequence="00", frame=0, kind="temporal"), estimators=("8point",)).to_dict()
    for e in (cli, doc):
        e.pop("recording", None)
        e.pop("timings")
        for r in e["estimators"]:
            r.pop("seconds")
    assert json.loads(json.dumps(doc)) == cli


def test_save_recording_reads_back_with_every_F(from_arrays, tmp_path):
    result = fviz.inspect_pair(from_arrays, estimators=("8point",), F={"mine": from_arrays.F_gt})
    path = fviz.save_recording(tmp_path / "mine.rrd", from_arrays, result, lines=12, probe=3)
    paths = R.entity_paths(path)
    for name in ("gt", "8point", "mine"):
        assert L.est("a", name, "epilines") in paths and L.est("b", name, "epilines") in paths
    (names,) = R.column(path, L.PAIR_METRICS, "estimators")
    assert names == ["gt", "8point", "mine"]
    (sed,) = R.column(path, L.PAIR_METRICS, "sed_median")
    assert sed == pytest.approx([r.metrics["sed_median"] for r in result.estimators])
    assert R.column(path, L.PROBE_TEXT, "probe", "probe") == [0, 1, 2]
    assert "mine" in R.blueprint_tabs(path)
    with pytest.raises(FvizError, match="path .*rrd"):
        fviz.save_recording(tmp_path / "mine.txt", from_arrays, result)


def test_log_result_into_the_callers_recording(from_arrays, tmp_path):
    result = fviz.inspect_pair(from_arrays, estimators=(), F={"mine": from_arrays.F_gt})
    rec = rr.RecordingStream("my-app")
    rec.save(str(tmp_path / "own.rrd"))
    fviz.log_result(rec, from_arrays, result, lines=5, probe=0, index=3)
    rec.log("my/own/thing", rr.TextDocument("the caller's"))
    rec.flush()
    rec.disconnect()
    path = tmp_path / "own.rrd"
    assert {"my/own/thing", "summary", L.image("a"), L.matches("gt")} <= set(R.entity_paths(path))
    assert R.column(path, L.SUMMARY, "pair") == [3]
    (xy,) = R.column(path, L.matches("gt"), "Points2D:positions")
    assert len(xy) == 2 * result.n_matches
    assert list(R.blueprint_tabs(path)) == ["overview", "mine", "probe"]  # the blueprint was sent
    with pytest.raises(FvizError, match="rec: expected a rerun.RecordingStream"):
        fviz.log_result("out.rrd", from_arrays, result)


def _synthetic_pairs(n=2):
    return [fviz.load_pair(synthetic=True, seed=s, kind="temporal") for s in range(n)]


def test_training_steps_show_the_lines_converge(tmp_path):
    pairs = _synthetic_pairs()
    true = np.stack([p.F_gt for p in pairs])
    rng = np.random.default_rng(0)
    noise = rng.normal(size=(2, 3, 3)) * np.abs(true).max()
    rec = rr.RecordingStream("my-training")
    rec.save(str(tmp_path / "train.rrd"))
    returned = [fviz.log_training_step(rec, step, pairs, true + w * noise, names=["left", "right"])
                for step, w in ((0, 1e-2), (10, 1e-3), (20, 0.0))]
    rec.flush()
    rec.disconnect()
    path = tmp_path / "train.rrd"
    assert R.column(path, L.watch("left", "sed_px"), "step", "step") == [0, 10, 20]
    sed = np.array([v[0] for v in R.column(path, L.watch("left", "sed_px"), "Scalars:scalars", "step")])
    np.testing.assert_allclose(sed, [r[0] for r in returned])
    assert sed[0] > sed[1] > sed[2] and sed[2] < 1e-6  # converging; exact at the truth
    # independently: the median SED of the first prediction on the fixed correspondences
    x_a, x_b = api.watch_points(pairs[0])
    assert sed[0] == pytest.approx(np.median(symmetric_epipolar_distance(true[0] + 1e-2 * noise[0], x_a, x_b)))
    assert len(R.column(path, L.watch("left", "a/image"), "EncodedImage:blob")) == 1  # images once, static
    assert len(R.column(path, L.watch("right", "b/gt"), "LineStrips2D:strips")) == 1  # the truth once
    assert len(R.column(path, L.watch("right", "b/net"), "LineStrips2D:strips")) == 3  # the network at each step
    (points,) = R.column(path, L.watch("left", "points"), "Points2D:positions", "step")[:1]
    assert len(points) == 2 * len(x_a) == 2 * api.WATCH_POINTS
    assert set(R.blueprint_tabs(path)) == {"pair left", "pair right"}
    with pytest.raises(FvizError, match=r"F_pred: expected shape \(2, 3, 3\)"):
        fviz.log_training_step(rec, 30, pairs, true[:1])
    with pytest.raises(FvizError, match="pairs\\[0\\]: .*ground truth"):
        fviz.log_training_step(rec, 30, [fviz.pair_from_images(pairs[0].image_a, pairs[0].image_b)], true[:1])


@pytest.mark.usefixtures("torch_one_thread")
@pytest.mark.parametrize("every, frames", [(0, [0, 2, 4, 6]), (3, [0, 3, 6])])  # at each checkpoint, or every 3 steps
def test_fviz_train_watches_validation_pairs(tmp_path, every, frames):
    import torch

    from fviz.train.checkpoint import read_checkpoint
    from fviz.train.curves import watched_pairs
    from fviz.train.loop import train
    from fviz.train.recipe import Recipe

    recipe = Recipe.from_dict({
        "model": {"variant": "siamese-rec-pos-fbn", "input_size": [32, 96], "width": 8, "hidden": 16, "pool_grid": [2, 4],
                  "dropout": 0.0},
        "data": {"source": "synthetic", "train_size": 8, "val_size": 4, "val_points": 32},
        "train": {"batch_size": 4, "lr": 1e-3, "epochs": 5, "max_steps": 6, "num_workers": 0, "out_dir": str(tmp_path / "run"),
                  "checkpoint_every": 2, "watch_pairs": 3, "watch_every": every},
    })
    res = train(recipe, record=True, held_out=False)
    path = res.recording
    assert {L.watch(str(i), w) for i in range(3) for w in ("a/image", "b/net", "points", "sed_px")} <= set(R.entity_paths(path))
    assert L.watch("3", "sed_px") not in R.entity_paths(path)
    assert R.column(path, L.watch("0", "sed_px"), "step", "step") == frames  # the start, then every few steps
    assert "curves" in R.blueprint_tabs(path) and "pair 0" in R.blueprint_tabs(path)
    # the last frame is the trained network's F on those pairs
    from fviz.models.model import FNet
    from fviz.train.checkpoint import load_into
    from fviz.train.splits import make_datasets

    ckpt = read_checkpoint(res.checkpoint)
    model = FNet.from_config(recipe.fnet_config())
    load_into(model, ckpt, what="last.pt")
    pairs, batch = watched_pairs(make_datasets(recipe)[1], 3, torch.device("cpu"))
    with torch.no_grad():
        F = model.eval()(*batch, strict_norm=False).double().numpy()
    assert ckpt["watch"][-1][0] == 6
    np.testing.assert_allclose(np.array(ckpt["watch"][-1][1]), F, rtol=1e-4, atol=1e-6)
    x_a, x_b = api.watch_points(pairs[1])
    last = R.column(path, L.watch("1", "sed_px"), "Scalars:scalars", "step")[-1][0]
    assert last == pytest.approx(np.median(symmetric_epipolar_distance(F[1], x_a, x_b)), rel=1e-4)
