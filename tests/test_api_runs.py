"""fviz.api.runs: a run from Python (select, evaluate_run, triage_run, compare_runs, run_table, read_run) gives what
the commands give, and its errors name the parameters, where the command line's name the flags."""

import os

import pytest

import fviz
from fviz.errors import FvizError, command_line


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "run"
    return fviz.evaluate_run(fviz.select(seeds=(0, 3)), out, estimators=("8point", "magsac"), max_keypoints=300, workers=1)


def test_a_synthetic_run_from_python(run):
    assert run.outcome.computed == 3 and not run.interrupted
    assert run.estimators == ["8point", "magsac"] and run.summary["pairs"] == 3
    assert [r["index"] for r in fviz.read_run(run.out_dir).records()] == [0, 1, 2]
    title, header, rows = run.figures()
    assert title == "synthetic seeds 0..2 (stereo): 3 pairs" and [r[0] for r in rows] == ["gt", "8point", "magsac"]
    triage = fviz.triage_run(run, by="magsac", top=2)
    assert triage.by == "magsac" and len(triage.ranked) == 3 and triage.markdown.is_file() and triage.recording.is_file()
    c = fviz.compare_runs(run, estimators=("8point", "magsac"))
    assert len(c.wins) + len(c.losses) + len(c.ties) == 3 and c.markdown == run.out_dir / "compare.md"
    assert c.recording.is_file() and dict(c.rows())
    md, csv = fviz.run_table(run.out_dir)
    assert md.is_file() and csv.is_file()
    again = fviz.evaluate_run(None, run.out_dir, resume=True, workers=1)  # as configured: nothing left to do
    assert (again.outcome.reused, again.outcome.computed) == (3, 0)


def test_two_runs_one_estimator(run, tmp_path):
    other = fviz.evaluate_run(fviz.select(seeds=(0, 3)), tmp_path / "b", estimators=("magsac",), max_keypoints=300,
                              threshold=2.0, workers=1)
    c = fviz.compare_runs(run, other, estimators="magsac", out=tmp_path / "c.md")
    assert c.markdown == tmp_path / "c.md" and c.a.run == run.out_dir and c.b.run == other.out_dir


@pytest.mark.parametrize("call, message", [
    (lambda tmp: fviz.select(seeds=(3, 1)), "^seeds 3:1: need 0 <= A < B"),
    (lambda tmp: fviz.select(seeds=(0, 2), kinds="sideways"), "^kinds 'sideways': choose one of"),
    (lambda tmp: fviz.select(seeds=(0, 2), sequence="00"), "^sequence: KITTI selections only"),
    (lambda tmp: fviz.evaluate_run(None, tmp / "nothing", resume=True), "^out_dir .*nothing: no run to resume"),
    (lambda tmp: fviz.evaluate_run(fviz.select(seeds=(0, 1)), tmp / "r", max_keypoints=0), "^max_keypoints 0: must be"),
    (lambda tmp: fviz.evaluate_run(fviz.select(seeds=(0, 1)), tmp / "r", colour=True), "^colour: not an option of a run"),
    (lambda tmp: fviz.read_run(tmp), "^out_dir .*: no run there"),
    (lambda tmp: fviz.compare_runs(tmp, estimators="magsac"), "^estimators 'magsac': two names on one run"),
])
def test_errors_name_the_parameter(tmp_path, call, message):
    with pytest.raises(FvizError, match=message):
        call(tmp_path)


def test_under_the_command_line_errors_name_the_flags(tmp_path):
    with command_line(), pytest.raises(FvizError, match="^--seeds 3:1: need 0 <= A < B"):
        fviz.select(seeds=(3, 1))
    with command_line(), pytest.raises(FvizError, match="^--out-dir .*: no run to resume"):
        fviz.evaluate_run(None, tmp_path / "nothing", resume=True)


def test_a_kitti_selection_defaults_to_the_environments_root(kitti_root, monkeypatch):
    monkeypatch.setenv("FVIZ_KITTI_ROOT", str(kitti_root))
    sel = fviz.select(sequence="00", frames=range(0, 2), kinds="temporal", steps=1)
    assert sel.kitti_root == os.path.abspath(kitti_root) and sel.frames == (0, 2) and sel.kinds == ("temporal",)
    monkeypatch.delenv("FVIZ_KITTI_ROOT")
    with pytest.raises(FvizError, match="^kitti_root: missing"):
        fviz.select(sequence="00")
