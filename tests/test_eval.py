"""``fviz eval`` / ``fviz merge`` on the real samples: reports agree, features are reused, resume and
Ctrl-C, shards, failures recorded, bad input."""

import json
import math
import signal
import subprocess
import sys
import time

import pyarrow.parquet as pq
import pytest
from cli_util import assert_one_line_error, invoke, read_csv, run_fviz
from rerun.chunk import RrdReader

from fviz.record import layout as L
from fviz.record.charts import CURVE_H
from fviz.record import reader as R

pytestmark = pytest.mark.kitti

SMALL = ("--max-keypoints", "400", "--no-progress")
ESTIMATORS = ("-e", "8point", "-e", "magsac", "-e", "oracle-mean")
SERIES = ["gt", "8point", "magsac", "oracle-mean"]
VOLATILE = ("seconds",)  # timings differ between runs


def fviz(*args):
    """Run the CLI in this process; return the result (callers check its exit code)."""
    return invoke(*args, check=False)


def eval_ok(*args):
    return invoke("eval", *args)




def as_float(v):
    return math.nan if v in ("", None) else float(v)


def same(a, b):
    return (math.isnan(a) and math.isnan(b)) or a == b


def jsonl(path):
    return [json.loads(line) for line in open(path)]


def rrd_rows(path):
    """entity -> list of {column: value} rows (timestamp columns dropped), static rows included."""
    out = {}
    for ch in RrdReader(str(path)).stream().to_chunks():
        rb = ch.to_record_batch()
        cols = [c for c in rb.schema.names if c not in ("rerun.controls.RowId", "log_time")]
        data = {c: rb.column(c).to_pylist() for c in cols}
        for i in range(rb.num_rows):
            out.setdefault(ch.entity_path.lstrip("/"), []).append({c: data[c][i] for c in cols})
    return out


def odometry_args(kitti_root, frames="0:8", kind="temporal"):
    return ("--kitti-root", kitti_root, "--sequence", "00", "--pair", kind, "--frames", frames)


@pytest.fixture(scope="module")
def run(kitti_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("eval") / "run"
    eval_ok(*odometry_args(kitti_root), *ESTIMATORS, *SMALL, "--workers", "1", "--out-dir", out)
    return out


def test_csv_has_one_row_per_pair_and_estimator(run):
    rows = read_csv(run / "metrics.csv")
    assert len(rows) == 7 * len(SERIES)
    assert [r["estimator"] for r in rows[: len(SERIES)]] == SERIES
    assert sorted({int(r["index"]) for r in rows}) == list(range(7))
    assert all(r["error"] == "" and r["pair_error"] == "" for r in rows)
    gt = [r for r in rows if r["estimator"] == "gt"]
    assert all(float(r["f_dist"]) == 0 for r in gt)


def test_parquet_equals_csv(run):
    rows = read_csv(run / "metrics.csv")
    table = pq.read_table(run / "metrics.parquet").to_pylist()
    assert len(table) == len(rows)
    for c, p in zip(rows, table):
        assert list(p) == list(c)
        for k, v in c.items():
            if isinstance(p[k], float) or p[k] is None:
                assert same(as_float(v), math.nan if p[k] is None else p[k]), k
            else:
                assert str(p[k]) == v, k


def test_summary_states_statistics_and_paper_table(run):
    text = (run / "summary.md").read_text()
    rows = read_csv(run / "metrics.csv")
    for word in ("mean", "median", "p90", "p99", "EPI-ABS FBN", "EPI-SQR ABS", "EPI-ABS ETR", "ground truth", "FBN", "means"):
        assert word in text
    # the paper table's magsac EPI-ABS FBN is the mean over pairs of the CSV's epi_abs_fbn
    mean = sum(float(r["epi_abs_fbn"]) for r in rows if r["estimator"] == "magsac") / 7
    paper = text.split("## Paper-style table")[1]
    line = next(ln for ln in paper.splitlines() if ln.startswith("| magsac |"))
    assert float(line.split("|")[2]) == pytest.approx(mean, rel=1e-3)


def test_recording_metrics_equal_csv(run):
    rows = read_csv(run / "metrics.csv")
    ents = rrd_rows(run / "eval.rrd")
    names = next(r["SeriesLines:names"] for r in ents[L.metric("sed_median")] if "SeriesLines:names" in r)
    assert names == SERIES
    info = {r["pair"]: r["TextDocument:text"][0] for r in ents[L.PAIR_INFO]}
    assert info == {int(r["index"]): r["name"] for r in rows}
    for key in ("sed_median", "inlier_ratio"):  # plotted series
        series = {r["pair"]: r["Scalars:scalars"] for r in ents[L.metric(key)] if "pair" in r}
        assert sorted(series) == list(range(7))
        for r in rows:
            value = series[int(r["index"])][SERIES.index(r["estimator"])]
            assert same(as_float(r[key]), value), (key, r["name"], r["estimator"])
    table = {r["pair"]: r for r in ents[L.PAIR_METRICS]}  # every metric, per pair
    assert sorted(table) == list(range(7))
    for r in rows:
        t = table[int(r["index"])]
        assert t["estimators"] == SERIES
        for key in ("sed_median", "epi_abs", "epi_sqr_fbn", "epipole_err_deg"):
            assert same(as_float(r[key]), t[key][SERIES.index(r["estimator"])]), (key, r["name"], r["estimator"])
    assert "a/image" not in ents  # light recording without --full


def test_cumulative_curves_equal_what_metrics_csv_gives(run):
    """eval.rrd's curves tab: per estimator the share of the pairs with pose error / SED / NSGD below each
    threshold (a failure never is), as recorded values and as the drawn curve, both from the CSV here."""
    import numpy as np

    rows = read_csv(run / "metrics.csv")
    for key in ("pose_err_deg", "sed_median", "nsgd"):
        entity = f"{L.CURVES}/{key}"
        thresholds = np.array(R.column(run / "eval.rrd", entity, "thresholds")[0])
        names = R.column(run / "eval.rrd", entity, "estimators")[0]
        recall = np.array(R.column(run / "eval.rrd", entity, "recall")[0]).reshape(len(names), len(thresholds))
        assert names == [n for n in SERIES if n != "gt"]
        strips = R.column(run / "eval.rrd", entity, "LineStrips2D:strips")[0]
        for i, name in enumerate(names):
            v = [as_float(r[key]) if not (r["error"] or r["pair_error"]) else math.inf for r in rows if r["estimator"] == name]
            v = [math.inf if math.isnan(x) else x for x in v]
            expected = [sum(x < t for x in v) / len(v) for t in thresholds]
            assert recall[i].tolist() == pytest.approx(expected), (key, name)
            drawn = np.array(strips[i])[:, 1]  # y down: the top of the panel is 100 %
            assert drawn.tolist() == pytest.approx((CURVE_H * (1 - np.array(expected))).tolist())
        assert thresholds[0] < 0.05 < thresholds[-1]  # FM-Bench's recall threshold inside every curve's range


def test_summary_tab_shows_the_runs_figures(run):
    doc = json.loads((run / "summary.json").read_text())
    tab = R.text(run / "eval.rrd", L.RUN_SUMMARY)
    assert len(tab) == 1 and "AUC@5°" in tab[0] and f"{doc['pairs']} pairs" in tab[0]
    line = next(ln for ln in tab[0].splitlines() if ln.startswith("| magsac |"))
    assert f"{doc['estimators']['magsac']['sed_median']:.4g}" in line


def test_resume_of_a_finished_run_recomputes_nothing(run):
    before = (run / "results.jsonl").read_bytes()
    r = eval_ok("--out-dir", run, "--resume", "--no-progress")
    assert (run / "results.jsonl").read_bytes() == before
    assert "0 evaluated now" in r.output


def test_existing_run_needs_resume_and_same_options(run, kitti_root):
    r = run_fviz("eval", "--out-dir", run, *odometry_args(kitti_root), *ESTIMATORS, *SMALL)
    assert_one_line_error(r, 2, "--resume")
    r = run_fviz("eval", "--out-dir", run, "--resume", *odometry_args(kitti_root, "0:9"), *ESTIMATORS, *SMALL)
    assert_one_line_error(r, 2, "(--frames 0:8 in the run, 0:9 now)")


@pytest.mark.slow
@pytest.mark.parametrize("workers", [1, 2])
def test_every_frame_is_detected_exactly_once(kitti_root, tmp_path, workers):
    out = tmp_path / "run"
    eval_ok(*odometry_args(kitti_root, "0:40"), "--pair", "stereo", "--step", "1,3", "-e", "8point",
            "--features", "orb", *SMALL, "--workers", workers, "--out-dir", out)
    records = jsonl(out / "results.jsonl")
    # every frame f: temporal f -> f+1 and f -> f+3 (camera 0), stereo at f (cameras 0, 1; image_1 has frame 0
    # only, so stereo pairs of later frames fail on loading and detect nothing)
    assert len(records) == 39 + 37 + 40
    assert sum(r["error"] is not None for r in records) == 39
    # the frame-aware schedule detects each of the 40 camera-0 frames and camera 1's frame 0 exactly once,
    # however the pairs fall on the workers (each record counts the detections made for it)
    assert sum(r["detections"] for r in records) == 41
    assert all(r["detections"] == 0 for r in records if r["error"])
    assert len({r["worker"] for r in records}) <= workers  # workers started once, not per pair


def test_shards_merge_to_the_same_results(run, kitti_root, tmp_path):
    for i in range(2):
        eval_ok(*odometry_args(kitti_root), *ESTIMATORS, *SMALL, "--shard", f"{i}/2", "--workers", "1",
                "--out-dir", tmp_path / f"s{i}")
    n0 = len(jsonl(tmp_path / "s0" / "results.jsonl"))
    assert 0 < n0 < 7
    r = fviz("merge", tmp_path / "s0", tmp_path / "s1", "--out-dir", tmp_path / "merged")
    assert r.exit_code == 0, r.output
    merged, single = read_csv(tmp_path / "merged" / "metrics.csv"), read_csv(run / "metrics.csv")
    assert len(merged) == len(single)
    for m, s in zip(merged, single):
        for k in s:
            if k not in VOLATILE:
                assert m[k] == s[k], (k, s["name"], s["estimator"])


def test_missing_image_is_recorded_and_the_run_goes_on(kitti_root, tmp_path):
    out = tmp_path / "run"
    # image_1 holds frame 0 only: stereo pairs of frames 1 and 2 cannot be loaded
    eval_ok(*odometry_args(kitti_root, "0:3", "stereo"), "--cams", "0,1", "-e", "magsac", *SMALL, "--out-dir", out)
    rows = read_csv(out / "metrics.csv")
    by_pair = {}
    for r in rows:
        by_pair.setdefault(int(r["index"]), []).append(r)
    assert sorted(by_pair) == [0, 1, 2]
    assert all(r["pair_error"] == "" for r in by_pair[0])
    for i in (1, 2):
        assert all("missing image" in r["pair_error"] and "image_1" in r["error"] for r in by_pair[i])
        assert all(r["sed_median"] in ("", "nan") for r in by_pair[i])
    ents = rrd_rows(out / "eval.rrd")
    assert sorted(r["pair"] for r in ents[L.PAIR_INFO]) == [0, 1, 2]
    assert {r["pair"] for r in ents[L.error("magsac")]} == {1, 2}


def test_full_recording_carries_images_and_keypoints(kitti_root, tmp_path):
    out = tmp_path / "run"
    eval_ok(*odometry_args(kitti_root, "0:3"), "-e", "magsac", *SMALL, "--full", "--out-dir", out)
    ents = rrd_rows(out / "eval.rrd")
    assert sorted(r["pair"] for r in ents[L.image("a")]) == [0, 1]
    kp = [r for r in ents[L.matches("magsac")]]  # runs: every estimator's own (a blueprint cannot vary per pair)
    assert sorted(r["pair"] for r in kp) == [0, 1]
    rows = read_csv(out / "metrics.csv")
    series = {r["pair"]: r["Scalars:scalars"] for r in ents[L.metric("sed_median")] if "pair" in r}
    assert series[1][1] == float(rows[3]["sed_median"])  # pair 1, magsac (after gt)


def _wait_for_lines(path, n, proc, timeout=120):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if path.is_file() and sum(1 for _ in open(path)) >= n:
            return
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    raise AssertionError("the run did not progress")


@pytest.mark.slow
@pytest.mark.parametrize("workers", [1, 2])
def test_ctrl_c_leaves_valid_partial_reports_that_resume_completes(kitti_root, tmp_path, workers):
    out = tmp_path / "run"
    args = [*odometry_args(kitti_root, "0:30"), "-e", "magsac", "--features", "orb", *SMALL, "--workers", str(workers),
            "--out-dir", str(out)]
    proc = subprocess.Popen([sys.executable, "-m", "fviz", "eval", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_lines(out / "results.jsonl", 3, proc)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "--resume" in err
    partial = jsonl(out / "results.jsonl")
    done = len(partial)
    assert 3 <= done < 29
    rows = read_csv(out / "metrics.csv")
    assert len(rows) == 2 * done
    assert {r["name"] for r in rows} == {r["key"] for r in partial}
    ents = rrd_rows(out / "eval.rrd")
    assert len(ents[L.PAIR_INFO]) == done

    eval_ok("--out-dir", out, "--resume", "--workers", workers, "--no-progress")
    final = jsonl(out / "results.jsonl")
    assert final[:done] == partial  # finished pairs untouched
    assert len(final) == 29 and len({r["key"] for r in final}) == 29
    assert len(read_csv(out / "metrics.csv")) == 2 * 29
    assert len(rrd_rows(out / "eval.rrd")[L.PAIR_INFO]) == 29


def test_synthetic_seeds(tmp_path):
    pytest.importorskip("fviz.data.synthetic")
    out = tmp_path / "run"
    eval_ok("--synthetic", "--seeds", "0:2", "--pair", "stereo", "-e", "magsac", "-e", "oracle-mean", *SMALL, "--out-dir", out)
    rows = read_csv(out / "metrics.csv")
    assert [r["name"] for r in rows[::3]] == ["synthetic/0/stereo/f000000c0-f000001c1", "synthetic/1/stereo/f000000c0-f000001c1"]
    assert all(r["error"] == "" for r in rows)
    # every synthetic stereo pair has the same F (same rig): the oracle-mean baseline is exact
    assert all(float(r["nsgd"]) < 1e-9 for r in rows if r["estimator"] == "oracle-mean")


@pytest.mark.parametrize("args, fragment", [
    (("--frames", "5:2"), "--frames"),
    (("--frames", "abc"), "--frames"),
    (("--frames", "0:999"), "--frames"),
    (("--shard", "3/2"), "--shard"),
    (("--shard", "x"), "--shard"),
    (("-e", "nope"), "--estimator"),
    (("--pair", "sideways"), "--pair"),
    (("--step", "0"), "--step"),
])
def test_bad_input_is_one_line_exit_2(kitti_root, tmp_path, args, fragment):
    r = run_fviz("eval", *odometry_args(kitti_root), *args, "--out-dir", tmp_path / "run")
    assert_one_line_error(r, 2, fragment)
    assert not (tmp_path / "run" / "results.jsonl").exists()


def test_merge_rejects_foreign_folders(tmp_path):
    (tmp_path / "empty").mkdir()
    r = run_fviz("merge", tmp_path / "empty", "--out-dir", tmp_path / "m")
    assert_one_line_error(r, 2, "merge")
