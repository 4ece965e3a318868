"""A user's estimator is isolated the same way on every path: copies of its inputs, its stdout kept off fviz's,
SystemExit / KeyboardInterrupt / a hang / a segfault recorded as its failure; what it returns (a torch tensor that
requires grad is its F; an array-like that will not convert, a complex F, an inlier mask of the wrong length are its
named failure, never a traceback or a silently altered result). Real ``fviz``
subprocesses with the estimators of faults/misbehaving_estimators.py."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from cli_util import read_csv, run_fviz

PROJECT = Path(__file__).resolve().parents[1]
FAULTS = Path(__file__).parent / "faults"
FAST = ("--max-keypoints", "400")
INSPECT = ("inspect", "pair", "--synthetic", "--seed", "0", *FAST)


def fviz(*args, cwd=PROJECT, timeout=600):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(PROJECT), str(FAULTS), os.environ.get("PYTHONPATH", "")]))
    return run_fviz(*args, cwd=cwd, timeout=timeout, env=env)


def by_name(doc):
    return {e["name"]: e for e in doc["estimators"]}


MISBEHAVING = ("chatty", "exits", "interrupts", "vandal", "hangs")


def test_misbehaving_estimators_are_isolated_in_inspect(tmp_path):
    """Printing, exit(3), KeyboardInterrupt, zeroing its inputs, hanging: each is that estimator's own
    failure (or output on stderr), and 8point after them gives what it gives alone."""
    specs = [a for name in MISBEHAVING for a in ("-e", f"misbehaving_estimators:{name}")]
    r = fviz(*INSPECT, *specs, "-e", "8point", "--estimator-timeout", "3", "--json", "--out", tmp_path / "x.rrd")
    alone = fviz(*INSPECT, "-e", "8point", "--json", "--out", tmp_path / "a.rrd")
    assert r.returncode == 1, r.stderr  # as for any failing estimator: the others' results are there
    ests = by_name(json.loads(r.stdout))  # stdout is the JSON alone: the chatty estimator's line went to stderr
    assert "chatty estimator says hello" in r.stderr and ests["chatty"]["error"] is None
    assert ests["exits"]["error"] == "SystemExit: called exit(3)"
    assert ests["interrupts"]["error"].startswith("KeyboardInterrupt")
    assert ests["hangs"]["error"] == "timed out after 3 s (--estimator-timeout)"
    ref = by_name(json.loads(alone.stdout))["8point"]
    assert ests["8point"]["F"] == ref["F"] and ests["8point"]["metrics"] == ref["metrics"]
    assert ests["chatty"]["F"] == ref["F"]


def test_misbehaving_estimators_are_recorded_in_eval(tmp_path):
    out = tmp_path / "run"
    specs = [a for name in ("exits", "interrupts", "hangs") for a in ("-e", f"misbehaving_estimators:{name}")]
    r = fviz("eval", "--synthetic", "--seeds", "0:1", *specs, "-e", "8point", *FAST, "--workers", "1", "--no-progress",
             "--estimator-timeout", "3", "--out-dir", out)
    assert r.returncode == 0, r.stderr
    assert "1 pairs (0 already done, 1 evaluated now, 0 not evaluated (pair errors)" in r.stderr
    errors = {row["estimator"]: row["error"] for row in read_csv(out / "metrics.csv")}
    assert errors["exits"] == "SystemExit: called exit(3)" and errors["interrupts"].startswith("KeyboardInterrupt")
    assert errors["hangs"] == "timed out after 3 s (--estimator-timeout)"
    assert errors["gt"] == errors["8point"] == ""


def test_an_estimator_given_as_a_file_path(tmp_path):
    (tmp_path / "helper.py").write_text("import cv2\n\ndef eight(x_a, x_b):\n"
                                        "    return cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)[0]\n")
    (tmp_path / "myest.py").write_text("from helper import eight\n\ndef fn(pair, x_a, x_b):\n    return eight(x_a, x_b)\n")
    specs = ("./myest.py:fn", f"{tmp_path}/myest.py:fn", "myest:fn")
    r = fviz(*INSPECT, *(a for spec in specs for a in ("-e", spec)), "-e", "8point", "--json", "--out", tmp_path / "x.rrd",
             cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    ests = by_name(json.loads(r.stdout))
    assert len(ests) == 5 and all(e["F"] == ests["8point"]["F"] for e in ests.values() if e["name"] != "gt")


def test_a_missing_estimator_file_is_one_line(tmp_path):
    r = fviz(*INSPECT, "-e", "./nothing.py:fn", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "error: --estimator ./nothing.py:fn: no such file nothing.py"], r.stderr


def test_odd_returns_are_named_failures_and_a_grad_tensor_is_an_f(tmp_path):
    names = ("grad_tensor", "unconvertible", "complex_f", "short_mask")
    r = fviz(*INSPECT, *[a for n in names for a in ("-e", f"misbehaving_estimators:{n}")], "-e", "8point", "--json",
             "--out", tmp_path / "x.rrd")
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    ests = by_name(json.loads(r.stdout))
    assert ests["grad_tensor"]["error"] is None
    np.testing.assert_allclose(np.array(ests["grad_tensor"]["F"]), np.array(ests["8point"]["F"]), rtol=1e-6, atol=1e-12)
    assert "refuses to convert" in ests["unconvertible"]["error"]
    assert "complex F" in ests["complex_f"]["error"]
    n = json.loads(r.stdout)["n_matches"]
    assert f"an inlier mask of {n - 1} entries for {n} matches" in ests["short_mask"]["error"]
    for name in names[1:]:
        assert f"error: estimator {name}: returned" in r.stderr


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_segfaulting_user_estimator_fails_its_pair_and_the_small_run_goes_on(tmp_path, workers):
    crash = Path(__file__).resolve().parent / "faults" / "crash_estimators.py"
    run = tmp_path / "run"
    r = run_fviz("eval", "--synthetic", "--seeds", "0:2", "-e", "8point", "-e", f"{crash}:segfault_on_1",
                 "--max-keypoints", "300", "--workers", workers, "--no-progress", "--out-dir", run)
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr, (r.returncode, r.stderr)
    recs = {rec["index"]: rec for rec in map(json.loads, (run / "results.jsonl").read_text().splitlines())}
    assert recs[0]["error"] is None and recs[1]["error"] == "the worker process evaluating this pair died"
    assert (run / "summary.md").is_file() and (run / "metrics.csv").is_file()
