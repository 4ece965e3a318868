"""train.rrd's watched pairs beside the constant, and clickable: ``fviz.log_training_step(..., F_baseline=...)`` draws a
baseline's lines and median SED beside the network's (checked against OpenCV's epipolar lines); ``fviz train`` passes
the training pairs' mean F, the same F validation sets the network beside (its reported SED recomputed from the F in the
file); a click in the page's server (its ClickApp, no browser) or the notebook viewer on a watched image is answered
with the point's lines under the ground truth, the network's F at the time cursor's step and the baseline's.
Read back from the saved .rrd with Rerun's own reader (``rerun.chunk.RrdReader``)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

import fviz
from fviz import api
from fviz.errors import FvizError
from fviz.record import layout as L

STEPS = ((0, 0.3, False), (10, 1e-4, True), (20, 0.0, True), (30, 0.0, False))  # (step, relative noise, with the baseline)


def _rows(path: Path, entity: str, column: str) -> dict[int | None, list]:
    """{step (None: static): the column's value} of one entity, with Rerun's reader."""
    out: dict[int | None, list] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for ch in RrdReader(path).stream().to_chunks():
            if ch.entity_path.strip("/") != entity:
                continue
            rb = ch.to_record_batch()
            if column not in rb.schema.names:
                continue
            steps = rb.column("step").to_pylist() if "step" in rb.schema.names else [None] * rb.num_rows
            out.update(zip(steps, rb.column(column).to_pylist()))
    return out


def _epiline(F: np.ndarray, x: np.ndarray, view: str) -> np.ndarray:
    """OpenCV's epipolar line (a, b, c), a^2 + b^2 = 1, of point x of image ``view`` in the other image."""
    return cv2.computeCorrespondEpilines(np.float32(x).reshape(1, 1, 2), 1 if view == "a" else 2, F).reshape(3)


def _on(seg, line, tol: float = 1e-2) -> bool:
    ends = np.c_[np.asarray(seg, float).reshape(-1, 2), np.ones(len(seg))]
    return bool(np.abs(ends @ line).max() < tol)


def _sed(F: np.ndarray, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """The symmetric epipolar distance (mean of both point-to-line distances) with OpenCV's lines."""
    l_b = cv2.computeCorrespondEpilines(np.float32(x_a).reshape(-1, 1, 2), 1, F).reshape(-1, 3)
    l_a = cv2.computeCorrespondEpilines(np.float32(x_b).reshape(-1, 1, 2), 2, F).reshape(-1, 3)
    d_b = np.abs(np.sum(l_b[:, :2] * x_b, 1) + l_b[:, 2])
    d_a = np.abs(np.sum(l_a[:, :2] * x_a, 1) + l_a[:, 2])
    return 0.5 * (d_a + d_b)


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """Two synthetic pairs watched at four steps, a stand-in network converging, the baseline (their mean F) at
    steps 10 and 20 only."""
    pairs = [fviz.synthetic_pair(seed=s, kind="temporal") for s in range(2)]
    true = np.stack([p.F_gt / np.linalg.norm(p.F_gt) for p in pairs])
    noise = np.random.default_rng(0).normal(size=(2, 3, 3))
    base = true.mean(0)
    path = tmp_path_factory.mktemp("watch") / "train.rrd"
    rec = rr.RecordingStream("my-training")
    rec.save(str(path))
    nets = {}
    for step, w, with_base in STEPS:
        nets[step] = true * (1 + w * noise)
        fviz.log_training_step(rec, step, pairs, nets[step], names=["left", "right"],
                               F_baseline=base if with_base else None, baseline_name="mean F")
    rec.flush()
    rec.disconnect()
    return path, pairs, nets, base


def test_the_baseline_is_drawn_and_measured_beside_the_network(logged):
    """Its lines of the fixed correspondences in both images lie on OpenCV's lines under the baseline's F, in the
    baseline's colour; its median SED in the residual plot is OpenCV's, beside the network's; at a step without it
    its lines are cleared; the layout names it."""
    path, pairs, nets, base = logged
    cyan = list(L.watch_colors()[L.BASELINE])
    for k, (name, p) in enumerate(zip(["left", "right"], pairs)):
        x_a, x_b = api.watch_points(p)
        for v, xs in (("b", x_a), ("a", x_b)):  # image b holds the lines of x_a, image a those of x_b
            strips = _rows(path, L.watch(name, f"{v}/{L.BASELINE}"), "LineStrips2D:strips")
            colors = _rows(path, L.watch(name, f"{v}/{L.BASELINE}"), "LineStrips2D:colors")
            assert sorted(strips) == [10, 20]
            lines = [_epiline(base, x, "a" if v == "b" else "b") for x in xs]
            segs = [s for s in strips[10] if len(s) == 2][: -2]  # the last two: the epipole's cross
            assert len(segs) >= len(xs) // 2, (name, v)  # most lines cross the image
            assert all(any(_on(s, line) for line in lines) for s in segs), (name, v)
            assert all(int(c) >> 8 == (cyan[0] << 16 | cyan[1] << 8 | cyan[2]) for c in colors[10])  # RGBA, A 255
            cleared = _rows(path, L.watch(name, f"{v}/{L.BASELINE}"), "Clear:is_recursive")
            assert sorted(cleared) == [30]  # the baseline of step 20 does not linger at step 30
        sed = _rows(path, L.watch(name, "sed_px/baseline"), "Scalars:scalars")
        assert sorted(sed) == [10, 20]
        assert sed[10][0] == pytest.approx(np.median(_sed(base, x_a, x_b)), rel=1e-4, abs=1e-4)  # OpenCV: float32
        net = _rows(path, L.watch(name, "sed_px"), "Scalars:scalars")
        assert sorted(net) == [0, 10, 20, 30]
        assert net[10][0] == pytest.approx(np.median(_sed(nets[10][k], x_a, x_b)), rel=1e-4, abs=1e-4)  # OpenCV: float32
        assert net[10][0] < sed[10][0]  # the plot says who is ahead: the network, here
        assert _rows(path, L.watch(name, "sed_px/baseline"), "SeriesLines:names")[None] == ["mean F"]
        assert _rows(path, L.watch(name, "sed_px"), "SeriesLines:names")[None] == ["network"]
        names = _rows(path, L.watch(name, "fundamental"), "estimators")
        assert names == {0: ["gt", "network"], 10: ["gt", "network", "mean F"], 20: ["gt", "network", "mean F"],
                         30: ["gt", "network"]}
        F = np.asarray(_rows(path, L.watch(name, "fundamental"), "F")[10]).reshape(-1, 3, 3)
        np.testing.assert_allclose(F, [p.F_gt, nets[10][k], base])
    assert "left: network (orange) vs mean F (cyan) vs ground truth (white)" in _view_names(path)


def _view_names(path: Path) -> set[str]:
    """The display names of the stored blueprint's views and containers."""
    from fviz.record import reader as R

    return {f["display_name"][0] for f in R._blueprint_fields(R.open_rrd(path)).values() if f.get("display_name")}


def test_log_training_step_refuses_a_bad_baseline(logged):
    _, pairs, nets, base = logged
    rec = rr.RecordingStream("bad")
    with pytest.raises(FvizError, match=r"F_baseline: expected shape \(2, 3, 3\)"):
        fviz.log_training_step(rec, 0, pairs, nets[0], F_baseline=np.zeros((3, 3, 3)))
    with pytest.raises(FvizError, match="baseline_name"):
        fviz.log_training_step(rec, 0, pairs, nets[0], F_baseline=base, baseline_name="network")


def _selection(path: str, position=None, instance=None) -> str:
    """The JSON the viewer sends for a click (Rerun 0.41: the root frame's [x, y, null] in a 2D view)."""
    item = {"type": "entity", "entity_path": path, "view_name": "pair"}
    if position is not None:
        item["position"] = [float(position[0]), float(position[1]), None]
    if instance is not None:
        item["instance_id"] = instance
    return json.dumps({"type": "selection_change", "application_id": "a", "recording_id": "r", "items": [item]})


def _time(step: float) -> str:
    return json.dumps({"type": "time_update", "application_id": "a", "recording_id": "r", "time": float(step)})


def _answer_strips(data: bytes, tmp: Path, entity: str) -> dict[int, list]:
    """{step: strips} the answer's bytes draw at ``entity``."""
    f = tmp / "answer.rrd"
    f.write_bytes(data)
    return _rows(f, entity, "LineStrips2D:strips")


def test_a_click_on_a_watched_image_draws_its_lines_under_each_f_at_each_step(logged, tmp_path):
    """The page's ClickApp on train.rrd: the time cursor at step 10, a click on pair "right"'s image a near one of its
    correspondences: snapped to it; its line in image b under the ground truth, the network of step 10 and the
    baseline (OpenCV's), under ``watch/right``; drawn at every step under that step's F's (step 0: the network's
    alone, no baseline). A click on a keypoint of pair "left" (its instance) is answered with pair left's lines."""
    from fviz.web.server import ClickApp

    path, pairs, nets, base = logged
    app = ClickApp(path)
    assert sorted(app.watched) == ["left", "right"] and not app.pairs
    _, answer = app.new_connection()
    assert answer(_time(10)) == []  # the cursor moves: nothing to draw yet
    x_a, x_b = api.watch_points(pairs[1])
    (data,) = answer(_selection("/watch/right/a/image", x_a[3] + 0.5))
    strips = _answer_strips(data, tmp_path, L.watch("right", "b/click"))
    assert sorted(strips) == [0, 10, 20, 30]
    want = {0: [pairs[1].F_gt, nets[0][1]], 10: [pairs[1].F_gt, nets[10][1], base], 20: [pairs[1].F_gt, base]}
    for step, Fs in want.items():
        segs = [s for s in strips[step] if len(s) == 2]
        for F in Fs:
            assert any(_on(s, _epiline(F, x_a[3], "a")) for s in segs), (step, F)
    assert not any(_on(s, _epiline(base, x_a[3], "a")) for s in strips[0] if len(s) == 2)  # no baseline at step 0
    ring = [s for s in strips[10] if len(s) > 2]  # the partner's ring, around x_b
    assert ring and np.allclose(np.mean(ring[0][:-1], 0), x_b[3], atol=1e-6)
    label = _rows(tmp_path / "answer.rrd", L.watch("right", "a/click/label"), "Points2D:labels")
    label = label.get(10) or _rows(tmp_path / "answer.rrd", L.watch("right", "b/click/label"), "Points2D:labels")[10]
    assert "mean F" in label[0] and "network" in label[0]
    assert not _rows(tmp_path / "answer.rrd", L.watch("left", "b/click"), "LineStrips2D:strips")  # the other pair untouched

    x_a0, _ = api.watch_points(pairs[0])
    (data,) = answer(_selection("/watch/left/points", None, instance=5))
    strips = _answer_strips(data, tmp_path, L.watch("left", "b/click"))
    assert any(_on(s, _epiline(nets[20][0], x_a0[5], "a")) for s in strips[20] if len(s) == 2)
    assert answer(_selection("/watch/left/a/image", [-40.0, 5.0])) == []  # off both images


def test_the_notebook_viewer_takes_clicks_on_train_rrd(logged):
    """fviz.notebook.open(train.rrd): ClickViewer.click on image b of the watched pair clicked last draws its line
    in image a (F^T x_b) under each F at the cursor's step (none seen: the last)."""
    import fviz.notebook

    path, pairs, nets, base = logged
    v = fviz.notebook.open(path)
    x = np.array([400.0, 150.0])
    c = v.click("b", *x)
    assert c is not None and c.view == "b" and c.names == ["gt", "network"]  # step 30: no baseline
    for k, F in enumerate([pairs[0].F_gt, nets[30][0]]):
        assert c.inside[k] and _on(c.segments[k], _epiline(F, c.point, "b"))


@pytest.mark.usefixtures("torch_one_thread")
def test_fviz_train_watches_beside_the_constant_validation_reports(tmp_path):
    """A short run (lr 0: 8 training pairs, one epoch of 2 steps) watching every validation pair: at the end of the
    epoch the baseline in train.rrd is the training pairs' mean F (fviz.estimators.baselines.mean_fundamental), the
    validation's ``mean_f_sed_px`` is that F's median SED on the validation's own points, and each watched pair's
    baseline SED is its median on the pair's fixed correspondences; the page's click at that step uses that F."""
    import torch
    from test_train import _recipe, _tiny_pairs

    from fviz.estimators.baselines import mean_fundamental
    from fviz.geometry import symmetric_epipolar_distance
    from fviz.record.rebuild import watch_pairs
    from fviz.train.curves import BASELINE
    from fviz.train.loop import train
    from fviz.train.losses import sample_points_on_geometry

    recipe = _recipe(tmp_path, lr=0.0, t_norm_weight=0.0, watch_pairs=4)
    train_ds, val_ds = _tiny_pairs(8), _tiny_pairs(4, seed=1)
    res = train(recipe, datasets=(train_ds, val_ds), record=True, held_out=False)
    path = res.recording
    rows = _rows(path, L.watch("2", "fundamental"), "estimators")
    assert rows == {0: ["gt", "network"], 2: ["gt", "network", BASELINE]}  # no training pair seen at step 0
    F_c = np.asarray(_rows(path, L.watch("2", "fundamental"), "F")[2]).reshape(-1, 3, 3)[2]
    want = mean_fundamental(train_ds.F.double().numpy())
    assert abs(np.sum(F_c / np.linalg.norm(F_c) * want / np.linalg.norm(want))) == pytest.approx(1.0, abs=1e-9)
    xa, xb = sample_points_on_geometry(val_ds.F, recipe.input_hw, recipe.data.val_points, torch.Generator().manual_seed(12345))
    sed = np.concatenate([symmetric_epipolar_distance(F_c, a[:, :2], b[:, :2]) for a, b in zip(xa.numpy(), xb.numpy())])
    assert res.metrics["mean_f_sed_px"] == pytest.approx(float(np.sort(sed)[(len(sed) - 1) // 2]), rel=1e-9)
    watched = watch_pairs(path)
    for k in range(4):
        F = np.asarray(_rows(path, L.watch(str(k), "fundamental"), "F")[2]).reshape(-1, 3, 3)[2]
        np.testing.assert_array_equal(F, F_c)  # one constant, in every pair's model-input pixels
        fs = watched[str(k)][2]
        x_a, x_b = fs.x_a, fs.x_b
        got = _rows(path, L.watch(str(k), "sed_px/baseline"), "Scalars:scalars")[2][0]
        assert got == pytest.approx(np.median(_sed(F_c, x_a, x_b)), rel=1e-4, abs=1e-4)  # OpenCV: float32
    assert f"0: network (orange) vs {BASELINE} (cyan) vs ground truth (white)" in _view_names(path)
