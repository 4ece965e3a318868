"""A user's estimator is isolated the same way on every path (issue 17): copies of its inputs, its stdout
kept off fviz's, SystemExit / KeyboardInterrupt / a hang recorded as its failure. Real ``fviz``
subprocesses with the estimators of faults/trust_estimators.py."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from cli_util import read_csv

PROJECT = Path(__file__).resolve().parents[1]
FAULTS = Path(__file__).parent / "faults"
FAST = ("--max-keypoints", "400")
INSPECT = ("inspect", "pair", "--synthetic", "--seed", "0", *FAST)


def fviz(*args, cwd=PROJECT, timeout=300):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(PROJECT), str(FAULTS), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-m", "fviz", *map(str, args)], capture_output=True, text=True, env=env,
                          cwd=cwd, timeout=timeout)


def by_name(doc):
    return {e["name"]: e for e in doc["estimators"]}


def test_an_estimator_that_prints_leaves_inspect_json_clean(tmp_path):
    r = fviz(*INSPECT, "-e", "trust_estimators:chatty", "--json", "--out", tmp_path / "x.rrd")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)  # stdout is the JSON alone
    assert by_name(doc)["chatty"]["error"] is None
    assert "chatty estimator says hello" in r.stderr


@pytest.mark.parametrize("name, said", [("exits", "SystemExit: called exit(3)"), ("interrupts", "KeyboardInterrupt")])
def test_exit_and_keyboard_interrupt_in_an_estimator_are_its_failure_in_inspect(tmp_path, name, said):
    r = fviz(*INSPECT, "-e", f"trust_estimators:{name}", "-e", "8point", "--json", "--out", tmp_path / "x.rrd")
    assert r.returncode == 1, r.stderr  # as for any failing estimator: the others' results are there
    ests = by_name(json.loads(r.stdout))
    assert said in ests[name]["error"]
    assert ests["8point"]["error"] is None and ests["8point"]["metrics"]["sed_median"] < 5


def test_exit_and_keyboard_interrupt_in_an_estimator_are_recorded_in_eval(tmp_path):
    out = tmp_path / "run"
    r = fviz("eval", "--synthetic", "--seeds", "0:2", "-e", "trust_estimators:exits", "-e", "trust_estimators:interrupts",
             "-e", "8point", *FAST, "--workers", "1", "--no-progress", "--out-dir", out)
    assert r.returncode == 0, r.stderr
    assert "2 pairs (0 already done, 2 evaluated now, 0 failed" in r.stderr
    rows = read_csv(out / "metrics.csv")
    assert {row["error"] for row in rows if row["estimator"] == "exits"} == {"SystemExit: called exit(3)"}
    assert all("KeyboardInterrupt" in row["error"] for row in rows if row["estimator"] == "interrupts")
    assert all(row["error"] == "" for row in rows if row["estimator"] in ("gt", "8point"))


def test_an_estimator_changing_its_inputs_harms_no_other(tmp_path):
    alone = fviz(*INSPECT, "-e", "8point", "--json", "--out", tmp_path / "a.rrd")
    after = fviz(*INSPECT, "-e", "trust_estimators:vandal", "-e", "8point", "--json", "--out", tmp_path / "b.rrd")
    assert alone.returncode == 0, alone.stderr
    a, b = by_name(json.loads(alone.stdout)), by_name(json.loads(after.stdout))
    assert b["8point"]["F"] == a["8point"]["F"]
    assert b["8point"]["metrics"] == a["8point"]["metrics"]


def test_a_hanging_estimator_fails_its_pair_after_the_timeout(tmp_path):
    r = fviz(*INSPECT, "-e", "trust_estimators:hangs", "-e", "8point", "--estimator-timeout", "3", "--json",
             "--out", tmp_path / "x.rrd")
    assert r.returncode == 1, r.stderr
    ests = by_name(json.loads(r.stdout))
    assert ests["hangs"]["error"] == "timed out after 3 s (--estimator-timeout)"
    assert ests["8point"]["error"] is None
    out = tmp_path / "run"
    e = fviz("eval", "--synthetic", "--seeds", "0:1", "-e", "trust_estimators:hangs", *FAST, "--workers", "1",
             "--no-progress", "--estimator-timeout", "3", "--out-dir", out)
    assert e.returncode == 0, e.stderr
    assert [row["error"] for row in read_csv(out / "metrics.csv") if row["estimator"] == "hangs"] == [
        "timed out after 3 s (--estimator-timeout)"]


def test_an_estimator_given_as_a_file_path(tmp_path):
    (tmp_path / "helper.py").write_text("import cv2\n\ndef eight(x_a, x_b):\n"
                                        "    return cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)[0]\n")
    (tmp_path / "myest.py").write_text("from helper import eight\n\ndef fn(pair, x_a, x_b):\n    return eight(x_a, x_b)\n")
    for spec in ("./myest.py:fn", f"{tmp_path}/myest.py:fn", "myest:fn"):
        r = fviz(*INSPECT, "-e", spec, "-e", "8point", "--json", "--out", tmp_path / "x.rrd", cwd=tmp_path)
        assert r.returncode == 0, (spec, r.stderr)
        ests = by_name(json.loads(r.stdout))
        assert ests["fn"]["F"] == ests["8point"]["F"], spec


def test_a_missing_estimator_file_is_one_line(tmp_path):
    r = fviz(*INSPECT, "-e", "./nothing.py:fn", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "error: --estimator ./nothing.py:fn: no such file nothing.py"], r.stderr
