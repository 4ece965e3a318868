"""fviz.record.reader on real recordings: one made by ``fviz inspect pair`` on the KITTI samples, and a
triage-like one (``rank`` and ``pair`` timelines, a failing estimator) written with the recording writer."""

from __future__ import annotations

import math

import pytest
from browser import inspect_recording

from fviz.errors import FvizError
from fviz.record import layout as L
from fviz.record import reader as R
from fviz.record.summary import read_recording

pytestmark = pytest.mark.kitti


@pytest.fixture(scope="module")
def inspected(kitti_root, tmp_path_factory):
    """(recording, the --json of the same run)."""
    return inspect_recording(kitti_root, tmp_path_factory.mktemp("reader") / "pair.rrd")


def _same(a, b) -> bool:
    """Equal floats, NaN/None meaning "no value" on both sides."""
    none_a = a is None or (isinstance(a, float) and math.isnan(a))
    none_b = b is None or (isinstance(b, float) and math.isnan(b))
    return none_a and none_b or (not none_a and not none_b and a == b)


def test_read_inspect_recording(inspected):
    path, doc = inspected
    s = read_recording(path)
    assert s.app_id == "fviz-inspect"
    assert s.timeline == "pair" and s.timelines == ("pair", "probe")
    assert s.has_blueprint
    assert s.estimators == tuple(e["name"] for e in doc["estimators"])
    keys = {k for e in doc["estimators"] for k in e["metrics"]}
    assert set(s.metrics) == keys and "sed_median" in keys
    assert [it.index for it in s.items] == [0]
    item = s.item(doc["pair"]["name"])
    assert item is s.item(0)
    assert item.errors == {} and item.times == {}  # the probe's timeline is not an item index
    for e in doc["estimators"]:
        for key in keys:
            assert _same(item.metrics[key][e["name"]], e["metrics"].get(key)), (key, e["name"])
    for ent in (L.image("a"), L.image("b"), L.PAIR_INFO, L.PAIR_METRICS, L.SUMMARY, L.COMPARE, L.epipoles("a"),
                L.matches("gt"), L.est("a", "ransac", "epilines"), L.est("b", "gt", "epilines"), L.probe("b"), "/"):
        assert ent in s.entity_paths
    assert s.entity_paths == tuple(R.entity_paths(path))
    assert R.timelines(path) == ["pair", "probe"]
    d = s.to_dict()
    assert d["path"] == str(path) and d["items"][0]["name"] == doc["pair"]["name"]


def test_helpers(inspected):
    path, doc = inspected
    assert R.text(path, L.PAIR_INFO) == [doc["pair"]["name"]]
    assert R.text(path, L.SUMMARY)[0].startswith(f"**{doc['pair']['name']}**")
    names = [e["name"] for e in doc["estimators"]]
    assert R.column(path, L.PAIR_METRICS, "estimators") == [names]
    # leading "/" accepted
    assert R.column(path, "/pair/metrics", "pair") == [0]
    assert R.column(path, L.PAIR_METRICS, "epi_abs") == [[e["metrics"]["epi_abs"] for e in doc["estimators"]]]
    classes = R.column(path, L.matches("gt"), "Points2D:class_ids")
    assert len(classes) == 1 and len(classes[0]) == 2 * doc["n_matches"]
    assert "EncodedImage:blob" in R.columns(path, L.image("a"))
    with pytest.raises(FvizError, match="no entity 'nope/x'"):
        R.column(path, "nope/x", "Scalars:scalars")
    with pytest.raises(FvizError, match="has no column 'nope'.*EncodedImage:blob"):
        R.column(path, L.image("a"), "nope")


def test_triage_like_recording(odometry, tmp_path):
    """Any timeline: items on ``rank`` (preferred), the ``pair`` index kept in ``times``; failures as NaN."""
    from fviz.estimators import get_estimator
    from fviz.evaluate import evaluate_pair
    from fviz.record.pair_recording import log_pair
    from fviz.record.run_plots import log_static
    from fviz.record.writer import RecordingWriter

    def broken(pair, x_a, x_b):
        raise RuntimeError("no luck")

    ests = [("8point", get_estimator("8point")), ("broken", broken)]
    names = ["gt", "8point", "broken"]
    path = tmp_path / "triage.rrd"
    frames = {0: 5, 1: 2}  # rank -> pair index (frame)
    results = {}
    with RecordingWriter(path, "fviz-triage") as w:
        log_static(w.rec, names, series=True)
        for rank, frame in frames.items():
            pair = odometry.pair(frame, "temporal")
            res = evaluate_pair(pair, ests)
            results[rank] = (pair, res)
            w.rec.set_time("rank", sequence=rank)
            log_pair(w.rec, frame, pair, res, single_pair=False)
    s = read_recording(path)
    assert s.app_id == "fviz-triage" and not s.has_blueprint
    assert s.timeline == "rank" and set(s.timelines) == {"rank", "pair"}
    assert s.estimators == tuple(names)
    assert [it.index for it in s.items] == [0, 1]
    for it in s.items:
        pair, res = results[it.index]
        assert it.name == pair.id.name
        assert it.times == {"pair": frames[it.index]}
        assert it.errors == {"broken": res.get("broken").error} == {"broken": "RuntimeError: no luck"}
        assert math.isnan(it.metrics["epi_abs"]["broken"])
        assert it.metrics["sed_median"]["8point"] == res.get("8point").metrics["sed_median"]
        assert it.estimators() == names
    assert s.to_dict()["items"][0]["metrics"]["epi_abs"]["broken"] is None
    # the same file read on its other timeline: items are pairs 2 and 5
    by_pair = read_recording(path, timeline="pair")
    assert [(it.index, it.times) for it in by_pair.items] == [(2, {"rank": 1}), (5, {"rank": 0})]
    with pytest.raises(FvizError, match="no timeline 'frame'"):
        read_recording(path, timeline="frame")


def _written(path, index: bool):
    """A small recording by fviz's writer: with Rerun's footer (``index``, as runs) or without it and ending
    with the end mark (as a single pair)."""
    import rerun as rr

    from fviz.record.writer import RecordingWriter

    with RecordingWriter(path, "fviz-test", index=index) as w:
        w.rec.set_time(L.TIMELINE, sequence=0)
        w.rec.log(L.PAIR_INFO, rr.TextDocument("p"))
    return path


def _without_end_mark(path):
    """The same data written by Rerun alone with no footer: every message intact and nothing after the
    data, as a single pair's file cut exactly before its end mark."""
    import rerun as rr

    rec = rr.RecordingStream("fviz-test")
    rec.save(str(path), write_footer=False)
    rec.set_time(L.TIMELINE, sequence=0)
    rec.log(L.PAIR_INFO, rr.TextDocument("p"))
    rec.flush()
    rec.disconnect()
    return path


@pytest.mark.parametrize("case", ["missing", "directory", "text", "empty", "half", "cut-end-mark", "no-end-mark",
                                  "no-footer"])
def test_bad_files(inspected, tmp_path, case):
    path, _ = inspected
    bad = tmp_path / f"{case}.rrd"
    data = path.read_bytes()
    run = _written(tmp_path / "run.rrd", index=True).read_bytes()
    if case == "directory":
        bad.mkdir()
    elif case == "text":
        bad.write_text("hello, not a recording\n")
    elif case == "empty":
        bad.write_bytes(b"")
    elif case == "half":
        bad.write_bytes(data[: len(data) // 2])
    elif case == "cut-end-mark":
        bad.write_bytes(data[:-1])  # a single pair's file (no footer), its last message cut
    elif case == "no-end-mark":
        _without_end_mark(bad)  # would read as a silently short file
    elif case == "no-footer":
        bad.write_bytes(run[:-1])  # a run's file, every frame intact, the footer cut: would read as a short file
    for fn in (read_recording, R.entity_paths, R.open_rrd):
        with pytest.raises(FvizError) as err:
            fn(bad)
        msg = str(err.value)
        assert "\n" not in msg and msg.startswith(str(bad)), msg
        if case in ("half", "cut-end-mark", "no-end-mark", "no-footer"):
            assert "truncated" in msg


@pytest.mark.parametrize("index", [True, False])
def test_complete_files_with_or_without_footer(tmp_path, index):
    path = _written(tmp_path / "ok.rrd", index=index)
    assert read_recording(path).items[0].name == "p"
    assert L.END in R.entity_paths(path) or index

