"""What a run folder holds is checked when read: run.json, results.jsonl and metrics.csv as a user, a crash or
another run may have left them; links planted in it are never written through, a crash's temporaries are removed,
shards are merged only when alike. Every case goes through the real ``fviz`` in a subprocess, on copies of
one small synthetic run."""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_util import assert_one_line_error, read_csv, run_fviz



FAST = ("--max-keypoints", "400", "--workers", "1", "--no-progress")
N = 2  # pairs of the run
RUN = ("--synthetic", "--seeds", f"0:{N}", "-e", "8point", "-e", "ransac", *FAST)
VOLATILE = {"seconds"}  # timings differ between two evaluations of one pair


def ok(*args):
    r = run_fviz(*args, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return r


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    out = tmp_path_factory.mktemp("trust") / "run"
    ok("eval", *RUN, "--out-dir", out)
    return out


@pytest.fixture
def run(finished, tmp_path):
    """A private copy of the finished run."""
    dest = tmp_path / "run"
    shutil.copytree(finished, dest)
    return dest


def lines(path):
    return [json.loads(line) for line in Path(path).read_text().splitlines()]


def write_lines(path, records):
    Path(path).write_text("".join(json.dumps(r) + "\n" for r in records))


def stable(rows):
    return [{k: v for k, v in r.items() if k not in VOLATILE} for r in rows]


# ------------------------------------------------------------------------------ tracebacks


@pytest.mark.parametrize("key, value, field", [
    (("eval_threshold",), "2", "eval_threshold"),
    (("selection", "frames"), "0:3", "selection.frames"),
    (("options", "max_keypoints"), "lots", "options.max_keypoints"),
    (("options", "names"), [3], "options.names"),
    (("bogus",), 1, "bogus"),
])
def test_a_run_json_with_wrong_types_is_one_line_naming_the_field(run, key, value, field):
    doc = json.loads((run / "run.json").read_text())
    target = doc
    for k in key[:-1]:
        target = target[k]
    target[key[-1]] = value
    (run / "run.json").write_text(json.dumps(doc))
    assert_one_line_error(run_fviz("eval", "--resume", "--out-dir", run, *FAST), 2, "run.json", field)


def _no_error_key(rec):
    del rec["error"]


def _text_metric(rec):
    rec["result"]["estimators"][1]["metrics"]["sed_median"] = "abc"


def _ref_without_fields(rec):
    del rec["ref"]["frame_a"]


def _small_F(rec):
    rec["result"]["estimators"][1]["F"] = [[1.0, 0.0], [0.0, 1.0]]


@pytest.mark.parametrize("damage", [_no_error_key, _text_metric, _ref_without_fields, _small_F])
def test_results_lines_that_are_json_but_not_records_are_skipped_and_evaluated_again(run, finished, damage):
    recs = lines(run / "results.jsonl")
    damage(recs[0])
    write_lines(run / "results.jsonl", recs)
    r = ok("eval", "--resume", "--out-dir", run, *FAST)
    assert "results.jsonl:1: not a pair record" in r.stderr
    assert "1 evaluated now" in r.stderr
    assert stable(read_csv(run / "metrics.csv")) == stable(read_csv(finished / "metrics.csv"))
    if damage is _small_F:  # triage and its recording read the records too
        write_lines(run / "results.jsonl", [recs[0], *lines(run / "results.jsonl")[1:]])  # the bad line again
        t = ok("triage", "--out-dir", run, *FAST)
        assert "not a pair record" in t.stderr


def test_text_in_metrics_csv_is_one_line_in_compare_and_table(run):
    text = (run / "metrics.csv").read_text().splitlines()
    header = text[0].split(",")
    col = header.index("sed_median")
    row = text[2].split(",")
    row[col] = "n/a"
    (run / "metrics.csv").write_text("\n".join([text[0], text[1], ",".join(row), *text[3:]]) + "\n")
    assert_one_line_error(run_fviz("compare", "--out-dir", run, "--a", "8point", "--b", "ransac"), 2,
                          "metrics.csv:3", "sed_median", "n/a")
    assert_one_line_error(run_fviz("table", run), 2, "metrics.csv:3", "sed_median")


@pytest.mark.parametrize("metric", ["name", "error", "estimator", "index"])
def test_compare_by_a_text_column_is_refused(run, metric):
    assert_one_line_error(run_fviz("compare", "--out-dir", run, "--a", "8point", "--b", "ransac", "--metric", metric),
                          2, f"--metric {metric}", "not a metric")


def test_table_of_an_empty_metrics_csv_is_refused(run):
    text = (run / "metrics.csv").read_text().splitlines()
    (run / "metrics.csv").write_text(text[0] + "\n")
    assert_one_line_error(run_fviz("table", run), 2, "metrics.csv", "no rows")
    assert not (run / "table.md").exists()


def test_a_truncated_payload_of_a_full_run_is_evaluated_again(tmp_path):
    out = tmp_path / "full"
    ok("eval", "--synthetic", "--seeds", "0:2", "-e", "8point", "--full", *FAST, "--out-dir", out)
    payload = out / "pairs" / "000000.npz"
    data = payload.read_bytes()
    payload.write_bytes(data[: len(data) // 2])
    r = ok("eval", "--resume", "--out-dir", out, *FAST)
    assert "1 evaluated now" in r.stderr
    with np.load(payload) as z:
        assert len(z["x_a"]) == len(z["eval_mask"]) > 0


# ------------------------------------------------------------------------------ silent wrong results


@pytest.fixture(scope="module")
def foreign(tmp_path_factory):
    """Records no seeds-0:N stereo run with these settings may use: one of --max-keypoints 100 (same pair),
    one of seed 7 and one of a temporal pair."""
    base = tmp_path_factory.mktemp("foreign")
    ok("eval", "--synthetic", "--seeds", "0:1", "-e", "8point", "-e", "ransac", *FAST[2:], "--max-keypoints", "100",
       "--out-dir", base / "k100")
    ok("eval", "--synthetic", "--seeds", "7:8", "--pair", "stereo,temporal", "-e", "8point", "-e", "ransac", *FAST,
       "--out-dir", base / "other")
    return [*lines(base / "k100" / "results.jsonl"), *lines(base / "other" / "results.jsonl")]


def test_records_of_other_settings_or_pairs_are_ignored_and_counted(run, finished, foreign, tmp_path):
    with open(run / "results.jsonl", "a") as f:
        f.writelines(json.dumps(r) + "\n" for r in foreign)
    r = ok("eval", "--resume", "--out-dir", run, *FAST)
    assert f"{N} already done, 0 evaluated now" in r.stderr
    assert "3 records ignored (1 made with other settings" in r.stderr and "2 of pairs outside" in r.stderr
    assert stable(read_csv(run / "metrics.csv")) == stable(read_csv(finished / "metrics.csv"))
    assert json.loads((run / "summary.json").read_text())["pairs"] == N
    t = ok("triage", "--out-dir", run, *FAST)
    assert "synthetic/7" not in (run / "triage.md").read_text()
    assert "records ignored" in t.stderr
    m = ok("merge", run, "--out-dir", tmp_path / "merged")
    assert "records ignored" in m.stderr
    assert stable(read_csv(tmp_path / "merged" / "metrics.csv")) == stable(read_csv(finished / "metrics.csv"))


def test_resume_after_run_json_is_deleted_recomputes_with_the_new_settings(run):
    (run / "run.json").unlink()
    r = ok("eval", "--resume", *RUN, "--max-keypoints", "100", "--eval-threshold", "5", "--out-dir", run)
    assert f"0 already done, {N} evaluated now" in r.stderr
    rows = read_csv(run / "metrics.csv")
    assert len(rows) == 3 * N and all(int(row["n_matches"]) <= 100 for row in rows)
    assert all(rec["result"]["eval_threshold_px"] == 5 for rec in lines(run / "results.jsonl")[N:])
    assert "(max 100" in (run / "summary.md").read_text()


def test_a_hand_edited_run_json_recomputes_instead_of_mixing_settings(run):
    doc = json.loads((run / "run.json").read_text())
    doc["options"]["max_keypoints"] = 100
    (run / "run.json").write_text(json.dumps(doc))
    r = ok("eval", "--resume", "--out-dir", run, *FAST[2:])
    assert f"0 already done, {N} evaluated now" in r.stderr and f"{N} records ignored" in r.stderr
    assert all(int(row["n_matches"]) <= 100 for row in read_csv(run / "metrics.csv"))


def test_resume_with_other_estimators_adds_the_missing_ones_and_keeps_the_others(run, finished, tmp_path):
    before = lines(run / "results.jsonl")
    r = ok("eval", "--resume", "--out-dir", run, "-e", "8point", "-e", "magsac", *FAST)
    assert "keeps the run's other estimators (ransac)" in r.stderr
    after = lines(run / "results.jsonl")
    assert len(after) == 2 * N
    for old, new in zip(before, after[N:]):
        assert new["estimators"] == ["8point", "ransac", "magsac"]
        # the estimators the pair had are kept as they were, not computed again (same timings)
        assert new["result"]["estimators"][:3] == old["result"]["estimators"]
    rows = read_csv(run / "metrics.csv")
    assert {r["estimator"] for r in rows} == {"gt", "8point", "ransac", "magsac"}
    ok("eval", "--synthetic", "--seeds", f"0:{N}", "-e", "magsac", *FAST, "--out-dir", tmp_path / "magsac")
    fresh = [r for r in read_csv(tmp_path / "magsac" / "metrics.csv") if r["estimator"] == "magsac"]
    assert stable([r for r in rows if r["estimator"] == "magsac"]) == stable(fresh)
    again = ok("eval", "--resume", "--out-dir", run, "-e", "8point", "-e", "ransac", "-e", "magsac", *FAST)
    assert f"{N} already done, 0 evaluated now" in again.stderr
    assert len(lines(run / "results.jsonl")) == 2 * N


# ------------------------------------------------------------------------------ data loss and security


def test_a_results_jsonl_symlink_is_refused_and_its_target_untouched(run, tmp_path):
    victim = tmp_path / "victim.jsonl"
    shutil.move(run / "results.jsonl", victim)
    kept = victim.read_bytes()
    (run / "results.jsonl").symlink_to(victim)
    assert_one_line_error(run_fviz("eval", "--resume", "--out-dir", run, *FAST), 2, "results.jsonl", "symlink")
    assert victim.read_bytes() == kept


def test_a_lock_that_is_a_planted_symlink_is_refused_and_its_target_untouched(tmp_path):
    out, victim = tmp_path / "run", tmp_path / "victim"
    out.mkdir()
    victim.write_text("precious\n")
    (out / ".fviz.lock").symlink_to(victim)
    assert_one_line_error(run_fviz("eval", *RUN, "--out-dir", out), 2, ".fviz.lock", "symlink")
    assert victim.read_text() == "precious\n"


def test_a_fifo_as_lock_is_refused(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    os.mkfifo(out / ".fviz.lock")
    assert_one_line_error(run_fviz("eval", *RUN, "--out-dir", out), 2, ".fviz.lock", "not a regular file")


def test_replaced_reports_keep_their_permissions(run):
    for name in ("metrics.csv", "summary.md", "eval.rrd"):
        os.chmod(run / name, 0o600)
    ok("eval", "--resume", "--out-dir", run, *FAST)
    for name in ("metrics.csv", "summary.md", "eval.rrd"):
        assert stat.S_IMODE(os.stat(run / name).st_mode) == 0o600, name


def test_merge_of_a_shard_still_running_is_refused(run, tmp_path):
    """The shard's lock is held by a real process (fviz's own lock, taken in a child that waits)."""
    go = tmp_path / "go"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time, pathlib\nfrom fviz.lock import locked\n"
         "with locked(sys.argv[1]):\n    print('held', flush=True)\n"
         "    while not pathlib.Path(sys.argv[2]).exists(): time.sleep(0.02)\n", str(run), str(go)],
        stdout=subprocess.PIPE, text=True, cwd=Path(__file__).resolve().parents[1])
    try:
        assert holder.stdout.readline().strip() == "held"
        assert_one_line_error(run_fviz("merge", run, "--out-dir", tmp_path / "merged"), 2,
                              "still being written", f"pid {holder.pid}")
        assert not (tmp_path / "merged" / "results.jsonl").exists()
    finally:
        go.touch()
        holder.wait(timeout=60)
    ok("merge", run, "--out-dir", tmp_path / "merged")


@pytest.mark.kitti
def test_the_default_stereo_selection_uses_only_frames_every_camera_has(kitti_root, tmp_path):
    """Sample sequence 00 has 50 frames of image_0 and one of image_1: the default run is that one pair, said so,
    not 49 failures; with --frames the user's range stands (a missing image is that pair's recorded failure)."""
    out = tmp_path / "run"
    r = ok("eval", "--kitti-root", kitti_root, "--sequence", "00", "-e", "8point", *FAST, "--out-dir", out)
    assert "image_1 of 00 has frames 0..0 only: the 49 later frames" in r.stderr
    assert "1 pairs (0 already done, 1 evaluated now, 0 not evaluated (pair errors)" in r.stderr
    figures = json.loads((out / "summary.json").read_text())
    assert figures["pairs"] == 1 and figures["estimators"]["gt"]["errors"] == 0


# ------------------------------------------------------------------------------ links and a crash's leftovers


@pytest.mark.parametrize("name", ["summary.md", "metrics.csv", "features.h5", "eval.rrd", "summary.json", "run.json"])
def test_a_link_planted_in_a_run_folder_is_never_written_through(finished, tmp_path, name):
    run, victim = tmp_path / "run", tmp_path / "victim"
    shutil.copytree(finished, run)
    victim.write_bytes(b"precious")
    (run / name).unlink(missing_ok=True)
    (run / name).symlink_to(victim)
    r = run_fviz("eval", "--resume", "--out-dir", run, *RUN)
    assert_one_line_error(r, 2, f"{run / name} is a symlink to {victim}, outside")
    assert victim.read_bytes() == b"precious"


def test_a_table_md_link_out_of_the_run_folder_is_never_written_through(finished, tmp_path):
    run, victim = tmp_path / "run", tmp_path / "victim"
    shutil.copytree(finished, run)
    victim.write_bytes(b"precious")
    (run / "table.md").symlink_to(victim)
    assert_one_line_error(run_fviz("table", run), 2, "table.md is a symlink to", "outside")
    assert victim.read_bytes() == b"precious"


def test_resume_removes_the_cache_temporaries_a_killed_run_left(finished, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(finished, run)
    left = [run / ".features.h5.tmpab12cd", run / ".matches.h5.tmp9x_y", run / ".summary.md.tmpQQ"]
    for p in left:
        p.write_bytes(b"partial")
    outside = tmp_path / "keep"
    outside.write_bytes(b"k")
    (run / ".metrics.csv.tmplink").symlink_to(outside)  # a link is never followed, only regular files go
    ok("eval", "--resume", "--out-dir", run, *RUN)
    assert not any(p.exists() for p in left)
    assert outside.read_bytes() == b"k"


# ------------------------------------------------------------------------------ merge


def test_merge_of_shards_with_other_settings_names_the_option_and_both_values(tmp_path):
    base = ("eval", "--synthetic", "--seeds", "0:2", "-e", "8point", "--workers", "1", "--no-progress")
    ok(*base, "--shard", "0/2", "--max-keypoints", "300", "--out-dir", tmp_path / "s0")
    ok(*base, "--shard", "1/2", "--max-keypoints", "200", "--out-dir", tmp_path / "s1")
    r = run_fviz("merge", tmp_path / "s0", tmp_path / "s1", "--out-dir", tmp_path / "m")
    assert_one_line_error(r, 2, f"merge: {tmp_path / 's1'} was run with other settings than {tmp_path / 's0'}",
                          f"--max-keypoints 300 in {tmp_path / 's0'}, 200 in {tmp_path / 's1'}")
