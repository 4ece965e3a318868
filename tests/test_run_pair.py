"""From a run to its pair (issue 42, item 2): ``fviz.read_pair`` rebuilds one pair of a run folder on demand, its F's
those results.jsonl holds, editable; ``fviz open RUN --pair`` writes and opens its recording."""

import json
import shutil

import numpy as np
import pytest
from rerun.chunk import RrdReader

import fviz
from fviz.errors import FvizError, command_line
from fviz.record import layout as L

pytestmark = pytest.mark.kitti

SETTINGS = dict(estimators=("8point", "magsac"), max_keypoints=400, workers=1)


@pytest.fixture(scope="module")
def run(tmp_path_factory, kitti_root):
    sel = fviz.select(kitti_root, sequence="00", frames=(0, 3), kinds="temporal")
    return fviz.evaluate_run(sel, tmp_path_factory.mktemp("runs") / "a", **SETTINGS)


def stored(run_dir, index):
    """{estimator: F} of the record of pair ``index`` in results.jsonl."""
    rec = next(r for r in map(json.loads, open(run_dir / "results.jsonl")) if r["index"] == index)
    return {e["name"]: np.array(e["F"]) for e in rec["result"]["estimators"]}


def entities(path):
    return {ch.entity_path.lstrip("/") for ch in RrdReader(str(path)).stream().to_chunks()}


def test_a_pair_read_back_has_the_runs_fs_and_is_editable(run):
    keys = [r["key"] for r in run.records()]
    for index, which in ((0, 0), (1, keys[1]), (1, keys[1].rsplit("/", 1)[1])):
        pair, result = fviz.read_pair(run, which)
        assert pair.id.name == keys[index] and not result.notes
        assert {e.name: e.F for e in result.estimators}.keys() == stored(run.out_dir, index).keys()
        for e in result.estimators:
            assert np.array_equal(e.F, stored(run.out_dir, index)[e.name]), e.name
    assert result.verdict is not None and result.matches is not None
    looser = fviz.reestimate(pair, result, threshold={"magsac": 3.0})  # editable as an inspect_pair result
    assert [e.name for e in looser.estimators] == ["gt", "8point", "magsac"]
    kept = fviz.edit(pair, result).exclude([0, 1])
    assert kept.n_matches == result.n_matches - 2


def test_without_the_cache_the_matches_are_computed_again(run, tmp_path):
    bare = tmp_path / "bare"
    shutil.copytree(run.out_dir, bare)
    for name in ("features.h5", "matches.h5"):
        (bare / name).unlink()
    pair, result = fviz.read_pair(bare, 1)
    assert any("matches computed again with the run's feature settings (sift)" in n for n in result.notes)
    assert all(np.array_equal(e.F, stored(bare, 1)[e.name]) for e in result.estimators)


def test_a_stored_f_that_differs_is_named(run, tmp_path):
    edited = tmp_path / "edited"
    shutil.copytree(run.out_dir, edited)
    lines = [json.loads(line) for line in open(edited / "results.jsonl")]
    magsac = next(e for e in lines[0]["result"]["estimators"] if e["name"] == "magsac")
    magsac["F"][0][0] += 1e-3
    (edited / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    _, result = fviz.read_pair(edited, 0)
    assert [n for n in result.notes if "F differs" in n] == [
        next(n for n in result.notes if n.startswith("magsac: its F differs from the run's in results.jsonl"))]


def test_its_recording_has_the_images_lines_and_fs(run):
    from fviz.api.runpairs import pair_recording

    path, pair, result = pair_recording(run.out_dir, 1)
    assert path == run.out_dir / "pairs" / (pair.id.name.replace("/", "_") + ".rrd")
    found = entities(path)
    assert {L.image("a"), L.image("b"), L.est("b", "magsac", "epilines"), L.est("b", "gt", "epilines"),
            L.matches("gt")} <= found
    from fviz.record.rebuild import click_pairs

    (fs,) = click_pairs(path).values()  # what a click is answered with: the run's F's
    assert fs.names == ["gt", "8point", "magsac"]
    assert all(np.array_equal(F, stored(run.out_dir, 1)[n]) for n, F in zip(fs.names, fs.F))


@pytest.mark.parametrize("which, message", [
    (7, r"^pair 7: not a pair of the run in .* \(2 pairs: an index 0..1 or a name such as odometry/00/temporal/"),
    ("nowhere", "^pair nowhere: not a pair of the run"),
    (-1, "^pair -1: expected a pair's index"),
    (True, "^pair True: expected a pair's index"),
])
def test_a_bad_pair_is_one_line_naming_it(run, which, message):
    with pytest.raises(FvizError, match=message):
        fviz.read_pair(run, which)


def test_a_bad_run_is_one_line_naming_it(tmp_path):
    with pytest.raises(FvizError, match="^run .*nothing: no run there \\(no such folder\\)"):
        fviz.read_pair(tmp_path / "nothing", 0)
    with pytest.raises(FvizError, match="^run .*: no run there \\(no run.json\\)"):
        fviz.read_pair(tmp_path, 0)
    with command_line(), pytest.raises(FvizError, match="^--pair 9: not a pair of the run"):
        fviz.read_pair(_any_run(tmp_path), 9)


def _any_run(tmp_path):
    sel = fviz.select(seeds=(0, 1))
    return fviz.evaluate_run(sel, tmp_path / "synthetic", estimators=("8point",), max_keypoints=200, workers=1)


def test_a_failed_pair_says_why(tmp_path):
    """A pair the run could not evaluate has no F's to rebuild: its record's error, in one line."""
    run = _any_run(tmp_path)
    lines = [json.loads(line) for line in open(run.out_dir / "results.jsonl")]
    lines[0].update(result=None, error="image a: no such file")
    (run.out_dir / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    with pytest.raises(FvizError, match=r"^pair 0: synthetic/.* was not evaluated in the run \(image a: no such file\)"):
        fviz.read_pair(run, 0)


# ---------------------------------------------------------------------------------------------- fviz open RUN --pair


def test_open_a_runs_pair_on_the_web_serves_it_editable(run):
    """``fviz open RUN --pair NAME --web``: the pair's recording written into RUN/pairs/, served with the edit tools."""
    import websocket
    from browser import WebServer

    key = next(run.records())["key"]
    with WebServer(run.out_dir, "--pair", key.rsplit("/", 1)[1]) as server:
        ws = websocket.create_connection(server.url.replace("http://", "ws://").replace("/?", "/ws?"), timeout=60)
        try:
            first, hello = ws.recv(), ws.recv()
        finally:
            ws.close()
    path = run.out_dir / "pairs" / (key.replace("/", "_") + ".rrd")
    assert first == path.read_bytes()  # the recording written, then the edit tools' state
    assert json.loads(hello)["fviz"] == "edit" and json.loads(hello)["fs"] == ["gt", "8point", "magsac"]
    assert f"recording: {path}" in "".join(server.lines)


@pytest.mark.parametrize("args, fragment", [
    (("--pair", "9"), "--pair 9: not a pair of the run in"),
    (("--pair", "0", "--tab", "nope"), "has no tab 'nope'"),
    ((), "a run folder, not a recording: open its recording"),
])
def test_open_a_runs_pair_errors_are_one_line(run, args, fragment):
    from browser import free_port
    from cli_util import assert_one_line_error, run_fviz

    r = run_fviz("open", run.out_dir, "--web", "--web-port", free_port(), *args)
    assert_one_line_error(r, 2, fragment)
    r = run_fviz("open", run.out_dir / "eval.rrd", "--pair", "0", "--web", "--web-port", free_port())
    assert_one_line_error(r, 2, "eval.rrd: a file, not a run folder")


def test_triage_lists_the_command_that_opens_each_pair(run, tmp_path):
    from cli_util import run_fviz

    r = run_fviz("triage", run.out_dir, "--top", "1", "--no-progress")
    assert r.returncode == 0, r.stderr
    ranked = (run.out_dir / "triage.md").read_text()
    key = ranked.split("### rank 0: `", 1)[1].split("`", 1)[0]
    command = f"fviz open {run.out_dir} --pair {key} --web"
    assert command in ranked and command in r.stdout


# ---------------------------------------------------------------------------------------------- eval.rrd's pairs on demand


def rows_by_time(data: bytes, tmp_path) -> dict[str, dict]:
    """What a page got: {entity: {pair index or "static": its last row}} of the bytes of a stream."""
    import warnings

    path = tmp_path / "got.rrd"
    path.write_bytes(data)
    out: dict[str, dict] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a stream's bytes have no footer
        for ch in RrdReader(str(path)).stream().to_chunks():
            rb = ch.to_record_batch()
            cols = {c: rb.column(c).to_pylist() for c in rb.schema.names if c not in ("rerun.controls.RowId", "log_time")}
            for i in range(rb.num_rows):
                t = cols["pair"][i] if "pair" in cols else "static"
                out.setdefault(ch.entity_path.lstrip("/"), {})[t] = {c: v[i] for c, v in cols.items()}
    return out


def test_the_page_of_a_runs_eval_rrd_draws_the_pair_the_time_cursor_reaches(run, tmp_path):
    """fviz open RUN/eval.rrd --web, without --full: a time update to pair i (a right-click in a plot moves the time
    cursor there) draws pair i (images, matches, lines, its F's), read from the run; a click on it is answered with
    its F's. The viewer's own time update on opening draws nothing; pair 0 drawn after pair 1 clears what 0 logged."""
    from fviz.api.runpairs import run_of_recording
    from fviz.web.server import ClickApp

    path = run.out_dir / "eval.rrd"
    app = ClickApp(path, run=run_of_recording(path))
    assert app.pairs == {} and app.run.indices == [0, 1]
    _, answer = app.new_connection()
    event = lambda kind, **kw: json.dumps({"application_id": app.ids[0], "recording_id": app.ids[1], "type": kind, **kw})
    assert answer(event("time_update", time=0.0)) == []  # the viewer's, as it opens
    (data,) = answer(event("time_update", time=1.0))
    got = rows_by_time(data, tmp_path)
    assert {L.image("a"), L.image("b"), L.est("b", "magsac", "epilines"), L.matches("gt")} <= got.keys()
    assert 1 in got[L.image("a")] and "pair/fundamental" in got
    stored_1 = stored(run.out_dir, 1)
    F = np.asarray(got["pair/fundamental"][1]["F"], float).reshape(-1, 3, 3)
    assert np.allclose(F, [stored_1[n] for n in ("gt", "8point", "magsac")], rtol=0, atol=1e-12)
    assert answer(event("time_update", time=1.0)) == []  # drawn once
    (data,) = answer(event("time_update", time=0.0))
    got = rows_by_time(data, tmp_path)
    assert 0 in got[L.image("a")] and 1 not in got[L.image("a")]  # pair 1 kept its own images (nothing cleared)
    x_a = fviz.read_pair(run, 0)[1].matches.x_a[0]  # a keypoint: the answer lists its residual under every F
    click = {"type": "entity", "entity_path": "/a/image", "position": [*map(float, x_a), None], "view_name": "overview"}
    (data,) = answer(event("selection_change", items=[click]))
    text = rows_by_time(data, tmp_path)["click/text"][0]
    assert all(f"| {n} |" in str(text) for n in ("gt", "8point", "magsac"))


# ---------------------------------------------------------------------------------------------- two runs on one pair


@pytest.fixture(scope="module")
def run_b(run, tmp_path_factory):
    """Another run of the same pairs: other estimators and a looser threshold, the same features (the same matches)."""
    return fviz.evaluate_run(run.config.selection, tmp_path_factory.mktemp("other") / "b",
                             estimators=("magsac", "ransac"), max_keypoints=400, threshold=2.0, workers=1)


def stored_metrics(run_dir, index):
    rec = next(r for r in map(json.loads, open(run_dir / "results.jsonl")) if r["index"] == index)
    return {e["name"]: e["metrics"] for e in rec["result"]["estimators"]}


def test_two_runs_on_one_pair_in_one_result(run, run_b):
    key = [r["key"] for r in run.records()][1]
    pair, both = fviz.read_pair(run, key, versus=run_b)
    assert [e.name for e in both.estimators] == ["gt", "a-8point", "a-magsac", "b-magsac", "b-ransac"]
    for label, folder in (("a", run.out_dir), ("b", run_b.out_dir)):
        index = next(r["index"] for r in fviz.read_run(folder).records() if r["key"] == key)
        Fs, metrics = stored(folder, index), stored_metrics(folder, index)
        for e in both.estimators:
            if e.name.startswith(label + "-"):
                name = e.name.split("-", 1)[1]
                assert np.array_equal(e.F, Fs[name]), e.name  # each run's own F and metrics
                assert e.metrics["sed_median"] == pytest.approx(metrics[name]["sed_median"], rel=1e-12), e.name
    assert any(n.startswith("a vs b: inlier threshold 1.0 and 2.0") for n in both.notes), both.notes
    assert not any("matches differ" in n for n in both.notes)
    assert fviz.reestimate(pair, both, threshold={"b-magsac": 3.0}).get("b-magsac").F is not None  # editable

    from fviz.api.runpairs import pair_recording
    from fviz.record.rebuild import click_pairs

    path, _, _ = pair_recording(run, key, versus=run_b, labels=("one", "two"))
    assert path.name.endswith(".vs-two.rrd")
    (fs,) = click_pairs(path).values()  # one click is answered with every F of both runs
    assert fs.names == ["gt", "one-8point", "one-magsac", "two-magsac", "two-ransac"]


def test_two_runs_whose_matches_differ_draw_the_first_runs(run, tmp_path):
    fewer = fviz.evaluate_run(run.config.selection, tmp_path / "fewer", estimators=("8point",), max_keypoints=250,
                              workers=1)
    pair, both = fviz.read_pair(run, 0, versus=fewer)
    _, own = fviz.read_pair(run, 0)
    assert [e.name for e in both.estimators] == ["gt", "a-8point", "a-magsac", "fewer-8point"]
    assert any(n.startswith("a vs fewer: the matches differ") and "drawn are the first run's" in n for n in both.notes)
    assert both.n_matches == own.n_matches and len(both.get("fewer-8point").residuals_px) == own.n_matches
    assert np.array_equal(both.get("fewer-8point").F, stored(fewer.out_dir, 0)["8point"])


@pytest.mark.parametrize("kwargs, message", [
    (dict(labels=("x", "x")), "^labels \\('x', 'x'\\): two different names"),
    (dict(labels=("x/y", "z")), "^labels .*: two different names"),
])
def test_versus_errors_name_the_parameter(run, run_b, kwargs, message):
    with pytest.raises(FvizError, match=message):
        fviz.read_pair(run, 0, versus=run_b, **kwargs)


def test_versus_a_run_without_the_pair(run, tmp_path):
    other = fviz.evaluate_run(fviz.select(seeds=(0, 1)), tmp_path / "synthetic", estimators=("8point",),
                              max_keypoints=200, workers=1)
    with pytest.raises(FvizError, match=r"^versus odometry/00/temporal/f000000c0-f000001c0: not a pair of the run in"):
        fviz.read_pair(run, 0, versus=other)
    with pytest.raises(FvizError, match=r"^versus .*nowhere: no run there"):
        fviz.read_pair(run, 0, versus=tmp_path / "nowhere")


def test_open_two_runs_on_one_pair_on_the_web(run, run_b):
    import websocket
    from browser import WebServer, free_port
    from cli_util import assert_one_line_error, run_fviz

    with WebServer(run.out_dir, "--pair", "1", "--versus", run_b.out_dir) as server:
        ws = websocket.create_connection(server.url.replace("http://", "ws://").replace("/?", "/ws?"), timeout=60)
        try:
            ws.recv()
            hello = json.loads(ws.recv())
        finally:
            ws.close()
    assert hello["fs"] == ["gt", "a-8point", "a-magsac", "b-magsac", "b-ransac"]
    assert any(".vs-b.rrd" in line for line in server.lines)
    r = run_fviz("open", run.out_dir / "eval.rrd", "--versus", run_b.out_dir, "--web", "--web-port", free_port())
    assert_one_line_error(r, 2, "--versus: only with --pair")


def test_compare_of_two_runs_lists_the_command_showing_both(run, run_b):
    va, vb = (stored_metrics(d, 0)[e]["sed_median"] for d, e in ((run.out_dir, "8point"), (run_b.out_dir, "magsac")))
    assert va != vb  # a threshold between them: only one side fails pair 0, which compare.md then lists
    c = fviz.compare_runs(run, run_b, estimators=("8point", "magsac"), fail_threshold=(va + vb) / 2,
                          out=run.out_dir / "c.md")
    key = next(run.records())["key"]
    assert f"`fviz open {run.out_dir} --pair {key} --versus {run_b.out_dir} --web`" in c.markdown.read_text()
