"""From compare.rrd's chart to its pair (issue 42, item 2): ``fviz open RUN/compare.rrd --web`` answers a click on a
pair's point of the chart by reading that pair from the run(s) compared and drawing it into the page (images,
matches, lines: clickable), on ``pair`` at its index, and moving the viewer's time cursor there."""

import json
import shutil

import numpy as np
import pytest
from test_run_pair import rows_by_time, stored

import fviz
from fviz.api.runpairs import ComparedPairs, run_of_recording
from fviz.record import layout as L
from fviz.record.compare_plot import COMPARE_POINTS, read_chart
from fviz.web.server import ClickApp


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two runs of three synthetic pairs: 8-point and MAGSAC++ in a, MAGSAC++ with a looser threshold in b."""
    root = tmp_path_factory.mktemp("compared")
    sel = fviz.select(seeds=(0, 3))
    a = fviz.evaluate_run(sel, root / "a", estimators=("8point", "magsac"), max_keypoints=200, workers=1)
    b = fviz.evaluate_run(sel, root / "b", estimators=("magsac",), max_keypoints=200, threshold=2.0, workers=1)
    return a, b


def page(rrd):
    """(the page's app, answer(kind, **fields) -> what the page gets back) for a fresh page on ``rrd``."""
    app = ClickApp(rrd, run=run_of_recording(rrd))
    _, answer = app.new_connection()
    ids = {"application_id": app.ids[0], "recording_id": app.ids[1]}
    return app, lambda kind, **kw: answer(json.dumps({**ids, "type": kind, **kw}))


def view_names(data: bytes, tmp_path) -> list[str]:
    """The views of the blueprint a page got with ``data``."""
    import warnings

    from rerun.chunk import RrdReader

    from fviz.record.reader import _blueprint_fields

    path = tmp_path / "blueprint.rrd"
    path.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a stream's bytes have no footer
        fields = _blueprint_fields(RrdReader(str(path)))
    return [f["display_name"][0] for ref, f in fields.items() if ref.startswith("view/") and ref.count("/") == 1]


def on_chart(chart, instance, dx=2.0):
    """A click on the chart's point ``instance`` (``dx`` to its right), as Rerun 0.41 reports it."""
    x, y = chart.points[instance]
    return {"type": "entity", "entity_path": "/" + COMPARE_POINTS, "instance_id": instance, "position": [x + dx, y, None],
            "view_name": chart.title}


def test_a_click_on_a_pairs_point_draws_that_pair_clickable(runs, tmp_path):
    """compare of two estimators of one run: a click on side b's point of pair 1 draws pair 1 (images, matches, every
    F of the run, as results.jsonl holds them) at ``pair`` = 1 with the pair's views, and moves the viewer there; a
    click on its image a is then answered with its F's; a click off the chart's pairs draws nothing."""
    a, _ = runs
    rrd = fviz.compare_runs(a, estimators=("8point", "magsac")).recording
    app, send = page(rrd)
    chart = app.run.chart
    assert isinstance(app.run, ComparedPairs) and chart.runs == (a.out_dir, a.out_dir) and app.run.indices == [0, 1, 2]
    data, moved = send("selection_change", items=[on_chart(chart, len(chart.names) + 1)])
    assert json.loads(moved) == {"fviz": "time", "timeline": "pair", "sequence": 1}
    got = rows_by_time(data, tmp_path)
    assert {L.image("a"), L.image("b"), L.matches("gt"), L.est("b", "magsac", "epilines")} <= got.keys()
    assert 1 in got[L.image("a")] and "Clear:is_recursive" in got[L.image("a")][2]  # pair 2, not drawn: no image
    views = view_names(data, tmp_path)  # the chart kept, the pair's images added below it
    assert chart.title in views and "compare.md" in views and any(v.startswith("ground truth: residuals") for v in views)
    F = np.asarray(got["pair/fundamental"][1]["F"], float).reshape(-1, 3, 3)
    assert got["pair/fundamental"][1]["estimators"] == ["gt", "8point", "magsac"]
    assert np.allclose(F, [stored(a.out_dir, 1)[n] for n in ("gt", "8point", "magsac")], rtol=0, atol=1e-12)
    pair, result = fviz.read_pair(a, 1)
    assert got[L.matches("gt")][1]["Points2D:positions"] is not None and pair.id.name == chart.names[1]
    x_a = result.matches.x_a[0]  # a keypoint of the pair drawn: the click is answered with every F's residual
    click = {"type": "entity", "entity_path": "/a/image", "position": [*map(float, x_a), None], "view_name": "overview"}
    (data,) = send("selection_change", items=[click])
    text = str(rows_by_time(data, tmp_path)["click/text"][1])
    assert all(f"| {n} |" in text for n in ("gt", "8point", "magsac"))
    # the same pair again: drawn already, the viewer moved there again; off the chart's pairs: nothing
    assert send("selection_change", items=[on_chart(chart, 1)]) == [json.dumps({"fviz": "time", "timeline": "pair", "sequence": 1})]
    assert send("selection_change", items=[{**on_chart(chart, 0), "position": [500.0, -65.0, None]}]) == []


def test_two_runs_compared_draw_both_runs_fs(runs, tmp_path):
    """compare of one estimator of two runs: the pair clicked is drawn with both runs' F's (``read_pair(...,
    versus=)``: "a-magsac", "b-magsac"), each that of its run's results.jsonl."""
    a, b = runs
    rrd = fviz.compare_runs(a, b, estimators="magsac", out=tmp_path / "ab.md").recording
    app, send = page(rrd)
    assert app.run.chart.runs == (a.out_dir, b.out_dir)
    data, moved = send("selection_change", items=[on_chart(app.run.chart, 2)])
    assert json.loads(moved)["sequence"] == 2
    fs = rows_by_time(data, tmp_path)["pair/fundamental"][2]
    assert fs["estimators"] == ["gt", "a-8point", "a-magsac", "b-magsac"]
    F = np.asarray(fs["F"], float).reshape(-1, 3, 3)
    want = [stored(a.out_dir, 2)[n] for n in ("gt", "8point", "magsac")] + [stored(b.out_dir, 2)["magsac"]]
    assert np.allclose(F, want, rtol=0, atol=1e-12)


def test_a_selection_maps_to_its_pair(runs, tmp_path):
    """Chart.pair_at: the point nearest the position (Rerun's entity and instance are the previous frame's), else the
    pair's column within the axes; the instance without a position; nothing off the chart or in another view."""
    a, _ = runs
    chart = read_chart(fviz.compare_runs(a, estimators=("8point", "magsac"), out=tmp_path / "c.md").recording)
    n = len(chart.names)
    assert chart.names == [r["key"] for r in a.records()] and chart.points.shape == (2 * n, 2)
    for k in range(2 * n):
        assert chart.pair_at(COMPARE_POINTS, k, [*chart.points[k], None], chart.title) == k % n
        assert chart.pair_at("/" + COMPARE_POINTS, k) == k % n  # no position: the instance
        assert chart.pair_at("compare/pairs", None, [chart.points[k][0] + 3.0, 100.0, None]) == k % n  # its column
        assert chart.pair_at("a/image", k, [*chart.points[k], None], "overview") is None  # another view
    assert chart.pair_at("a/image", 0, [*chart.points[0], None], chart.title) == 0  # a stale entity, on the chart
    assert chart.pair_at(COMPARE_POINTS, None, [500.0, -65.0, None], chart.title) is None  # the chart's title


def test_only_a_compare_rrd_whose_runs_are_there_is_clickable(runs, tmp_path, capsys):
    a, _ = runs
    moved = tmp_path / "moved"
    shutil.copytree(a.out_dir, moved / "a")
    rrd = fviz.compare_runs(moved / "a", estimators=("8point", "magsac"), force=True).recording
    assert isinstance(run_of_recording(rrd), ComparedPairs)  # the run found relative to the recording
    shutil.move(moved / "a", tmp_path / "elsewhere")
    shutil.copy(tmp_path / "elsewhere" / "compare.rrd", moved / "compare.rrd")
    assert run_of_recording(moved / "compare.rrd") is None
    assert "a click on a pair draws nothing: run " in capsys.readouterr().err
    assert run_of_recording(tmp_path / "elsewhere" / "compare.rrd") is not None
    assert read_chart(a.out_dir / "eval.rrd") is None
