"""The verdict corpus (benchmarks/verdict_corpus.py): pairs of known cause judged by fviz's verdicts. The
quick corpus (~40 cases, a few seconds) must do no worse than the committed baseline
(benchmarks/verdict_corpus_baseline.json: per-cause precision and recall, the target figures); the targets
themselves hold (false fine 0 where fviz is given the true ground truth, gt-suspect precision >= 0.95 and recall >= 0.8
on corruptions that move F_gt's lines, no claim below the minimum)."""

from __future__ import annotations

import importlib.util
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

pytestmark = pytest.mark.kitti

PROJECT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("verdict_corpus", PROJECT / "benchmarks" / "verdict_corpus.py")
vc = sys.modules["verdict_corpus"] = importlib.util.module_from_spec(_spec)  # registered: its dataclasses need it
_spec.loader.exec_module(vc)
TOL = 1e-9


@pytest.fixture(scope="module")
def quick(kitti_root):
    summary, rows, _ = vc.run_corpus(quick=True, kitti_root=kitti_root)
    return summary, rows


@pytest.fixture(scope="module")
def baseline():
    return json.loads(vc.BASELINE.read_text())


def test_the_quick_corpus_covers_every_cause(quick):
    summary, rows = quick
    built = {r["built_as"] for r in rows}
    assert built == set(vc.LABELS)
    assert len({r["name"] for r in rows}) == len(rows), "case names are unique"
    assert all(r["n_matches"] >= 8 for r in rows)


def test_the_corpus_is_the_baselines(quick, baseline):
    assert quick[0]["cases"] == baseline["cases"], (
        "the quick corpus changed: rewrite the baseline (python benchmarks/verdict_corpus.py --quick --write-baseline)")


def _worse(now, before, higher_is_better: bool) -> bool:
    if before is None or now is None:  # nothing predicted that cause, before or now: no precision to compare
        return False
    return now < before - TOL if higher_is_better else now > before + TOL


def test_no_figure_is_worse_than_the_baseline(quick, baseline):
    summary = quick[0]
    now = vc.baseline_figures(summary)
    worse = []
    for cause, before in baseline["per_cause"].items():
        for k in ("precision", "recall"):
            if _worse(now["per_cause"][cause][k], before[k], True):
                worse.append(f"{cause} {k}: {now['per_cause'][cause][k]:.3f} < {before[k]:.3f}")
    for k, higher in (("false_fine", False), ("false_fine_true_gt", False), ("claims_below_minimum", False),
                      ("gt_precision", True), ("gt_recall", True), ("gt_recall_visible", True)):
        if _worse(now["targets"][k], baseline["targets"][k], higher):
            worse.append(f"{k}: {now['targets'][k]} against {baseline['targets'][k]}")
    assert not worse, "worse than benchmarks/verdict_corpus_baseline.json: " + "; ".join(worse)


def test_the_issue_targets(quick):
    summary, rows = quick
    t = summary["targets"]
    assert t["false_fine_true_gt"] == 0, summary["false_fine_cases"]
    assert t["gt_precision"] is not None and t["gt_precision"] >= vc.TARGETS["gt_precision"]
    assert t["gt_recall_visible"] >= vc.TARGETS["gt_recall_visible"]
    assert t["claims_below_minimum"] == 0, summary["claims_below_minimum_cases"]


@dataclass(frozen=True)
class _V:
    kind: str
    text: str
    detail: str = ""


def test_verdicts_map_to_causes_today_and_with_the_new_kinds():
    assert vc.predicted_cause(_V("no failure", "")) == "correct"
    assert vc.predicted_cause(_V("ground truth suspect", "")) == "gt"
    assert vc.predicted_cause(_V("pair failed", "")) == "pair_failed"
    assert vc.predicted_cause(_V("too few to judge", "")) == "too_few"
    assert vc.predicted_cause(_V("inputs suspect", "", "swapped")) == "inputs:swapped"
    assert vc.predicted_cause(_V("inputs suspect", "", "K")) == "inputs:K"
    assert vc.predicted_cause(_V("inputs suspect", "")) == "inputs"
    assert vc.predicted_cause(_V("something new", "")) == "other:something new"


def test_what_a_verdict_calls_fine():
    judged = ["8point", "ransac", "magsac"]
    assert vc.called_fine(_V("no failure", "..."), judged) == judged
    text = "8point fails (pose error 45 deg) although 95% of the 905 matches lie within 2 px of F_gt: not the matcher; ransac, magsac fine"
    assert vc.called_fine(_V("estimator", text), judged) == ["ransac", "magsac"]
    assert vc.called_fine(_V("matcher", "8point (...) and ransac (...) fail but only 12%: the matcher's fault"), judged) == []
    assert vc.called_fine(_V("ground truth suspect", "magsac's inliers sit 3 px off: trust magsac's F"), judged) == []
