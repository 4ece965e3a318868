"""examples/: the quickstart script, the notebook (executed headless with nbclient) and a user's own training
loop run on the shared KITTI samples, using only the public API; their printed figures and files are checked."""

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fviz.record import layout as L
from fviz.record import reader as R

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _env(kitti_root, **more):
    env = dict(os.environ, FVIZ_KITTI_ROOT=str(kitti_root), **more)
    env["PYTHONPATH"] = os.pathsep.join([str(EXAMPLES.parent), env.get("PYTHONPATH", "")])
    return env


def _sed_rows(text: str) -> dict[str, float]:
    return {m[1]: float(m[2]) for m in re.finditer(r"^(\S+)\s+SED\s+([0-9.]+) px", text, re.M)}


def test_examples_use_only_the_public_api():
    for path in EXAMPLES.glob("*.py"):
        imports = re.findall(r"^\s*(?:from|import) (fviz\S*)", path.read_text(), re.M)
        assert imports == ["fviz"], (path.name, imports)


def test_quickstart_script(kitti_root, tmp_path):
    proc = subprocess.run([sys.executable, str(EXAMPLES / "quickstart.py"), str(tmp_path / "q.rrd")], capture_output=True,
                          text=True, cwd=tmp_path, env=_env(kitti_root), timeout=300)
    assert proc.returncode == 0, proc.stderr
    sed = _sed_rows(proc.stdout)
    assert list(sed) == ["gt", "8point", "magsac", "mine"]
    assert sed["gt"] < 0.5 and sed["magsac"] < 0.5 < sed["mine"] < 5  # KITTI's stereo truth is good to ~0.3 px
    (names,) = R.column(tmp_path / "q.rrd", L.PAIR_METRICS, "estimators")
    assert names == ["gt", "8point", "magsac", "mine"]
    (values,) = R.column(tmp_path / "q.rrd", L.PAIR_METRICS, "sed_median")
    np.testing.assert_allclose(values, list(sed.values()), atol=5e-4)  # the printed figures are the recorded ones


def _run_notebook(name: str, kitti_root, out, after: dict[str, str] | None = None) -> list:
    """Execute ``examples/NAME`` headless (its kernel inherits FVIZ_OUT=out and the KITTI root) -> its code cells' outputs.
    ``after``: {text in a code cell: code run right after that cell (what a user does between two cells: a click)}."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    nb = nbformat.read(EXAMPLES / name, as_version=4)
    for marker, code in (after or {}).items():
        (at,) = [i for i, c in enumerate(nb.cells) if c.cell_type == "code" and marker in c.source]
        nb.cells.insert(at + 1, nbformat.v4.new_code_cell(code))
    env_before = dict(os.environ)
    os.environ.update(_env(kitti_root, FVIZ_OUT=str(out)))
    try:
        nbclient.NotebookClient(nb, kernel_name="python3", timeout=300, resources={"metadata": {"path": str(EXAMPLES)}}).execute()
    finally:
        os.environ.clear()
        os.environ.update(env_before)
    return [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]


# A click on a keypoint of image a as the widget sends it (a SelectionChangeEvent's JSON, tests/test_interactive.py
# _selection), 1 px beside the match end nearest (300, 150), fed to the notebook's viewer between two cells; the click
# (its point, match, F's and clipped lines) printed for the test.
CLICK = """
import json
_j = int(np.argmin(np.linalg.norm(result.matches.x_a - [300.0, 150.0], axis=1)))
_x = result.matches.x_a[_j] + 1.0
_item = {"type": "entity", "entity_path": "/a/image", "view_name": "overview", "position": [float(_x[0]), float(_x[1]), None]}
_c = viewer.handle(json.dumps({"type": "selection_change", "application_id": "fviz-notebook", "recording_id": "r",
                               "items": [_item]}))
print("CLICKED " + json.dumps({"match": _j, "x_a": result.matches.x_a[_j].tolist(), "view": _c.view, "got": _c.match,
                               "point": _c.point.tolist(), "names": _c.names, "inside": _c.inside.tolist(),
                               "segments": np.nan_to_num(_c.segments).tolist(),
                               "F": {r.name: r.F.tolist() for r in result.estimators if r.F is not None}}))
"""


def _check_click(text: str) -> dict:
    """The injected click drew, in image b, the clicked point's epipolar line under every F where OpenCV puts it
    (computeCorrespondEpilines of the printed F's, independent of fviz); the next cell read it as ``viewer.last``."""
    import json

    import cv2

    (line,) = re.findall(r"^CLICKED (.*)$", text, re.M)
    c = json.loads(line)
    assert c["view"] == "a" and c["got"] == c["match"] and np.allclose(c["point"], c["x_a"]), c
    assert c["names"] == ["gt", "magsac", "mine"] and all(c["inside"]), c
    for name, seg in zip(c["names"], c["segments"]):
        epi = cv2.computeCorrespondEpilines(np.float32(c["point"]).reshape(1, 1, 2), 1, np.array(c["F"][name])).reshape(3)
        ends = np.c_[np.asarray(seg, float), np.ones(2)]
        assert np.abs(ends @ epi / np.hypot(*epi[:2])).max() < 1e-2, name
    x, y = c["point"]
    assert f"click in image a at ({x:.1f}, {y:.1f}), match {c['match']}" in text, text  # viewer.last, not the fallback
    return c


def test_notebook_runs_headless(kitti_root, tmp_path):
    outputs = _run_notebook("quickstart.ipynb", kitti_root, tmp_path, after={"fviz.notebook.show(pair, result)": CLICK})
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    c = _check_click(text)
    robust = re.search(r"^re-estimated: mine_ransac median SED ([0-9.]+) px \(mine ([0-9.]+) px\)", text, re.M)
    assert robust and float(robust[1]) < float(robust[2]), text  # the robust fit is the better one
    assert re.search(rf"^\s+mine_ransac\s+residual [0-9.]+ px at match {c['match']}$", text, re.M), text  # same point
    sed = _sed_rows(text)
    assert list(sed) == ["gt", "magsac", "mine"] and sed["magsac"] < 0.5 < sed["mine"]
    assert f"saved {tmp_path / 'notebook_pair.rrd'}" in text and (tmp_path / "notebook_pair.rrd").is_file()
    edited = re.search(r"^edited: (\d+) of (\d+) matches kept, magsac median SED ([0-9.]+) px \(was ([0-9.]+)\)", text, re.M)
    assert edited and 0 < int(edited[1]) < int(edited[2]) and float(edited[3]) <= float(edited[4]), text  # off-F matches gone
    assert "exported: F.json, features.h5, matches.h5, matches.txt" in text and (tmp_path / "edited" / "matches.h5").is_file()
    steps = [[float(v) for v in m.split(", ")] for m in re.findall(r"^step \d+: median SED \[(.*)\] px", text, re.M)]
    assert len(steps) == 6 and all(last < first / 10 for first, last in zip(steps[0], steps[-1]))  # converging
    widgets = [o for o in outputs if o.output_type == "display_data" and "application/vnd.jupyter.widget-view+json" in o.data]
    assert len(widgets) >= 2  # the viewer, shown twice


def test_own_training_loop(kitti_root, tmp_path):
    proc = subprocess.run([sys.executable, str(EXAMPLES / "own_training_loop.py"), str(tmp_path / "own.rrd"), "60"],
                          capture_output=True, text=True, cwd=tmp_path, env=_env(kitti_root), timeout=600)
    assert proc.returncode == 0, proc.stderr
    printed = {int(s): [float(v) for v in m.split(", ")]
               for s, m in re.findall(r"^step\s+(\d+): median SED on the watched pairs \[(.*)\] px", proc.stdout, re.M)}
    assert list(printed) == list(range(0, 61, 10))
    path = tmp_path / "own.rrd"
    assert R.column(path, L.watch("f44", "sed_px"), "step", "step") == list(printed)
    recorded = [v[0] for v in R.column(path, L.watch("f44", "sed_px"), "Scalars:scalars", "step")]
    np.testing.assert_allclose(recorded, [v[0] for v in printed.values()], rtol=1e-3)
    assert np.median(printed[60]) < np.median(printed[0]) / 5  # the network learnt


def _runs_figures(text: str, run_dir: Path) -> None:
    """What examples/runs.py and runs.ipynb print and write: eval -> triage -> compare -> table on 5 KITTI pairs."""
    assert f"evaluated 5 pairs into {run_dir}" in text, text
    sed = {m[1]: float(m[2]) for m in re.finditer(r"^(\w+)\s+median SED ([0-9.]+) px", text, re.M)}
    assert list(sed) == ["gt", "8point", "magsac"] and sed["magsac"] < sed["8point"], text
    assert len(re.findall(r"^worst #\d: odometry/00/", text, re.M)) == 3, text
    wins = re.search(r"^8point vs magsac: (\d+) wins, (\d+) losses, (\d+) ties", text, re.M)
    assert wins and sum(map(int, wins.groups())) >= 1, text
    assert "| Method | ETR EPI-ABS" in text and "read back: 5 pairs, estimators 8point, magsac" in text, text
    for name in ("results.jsonl", "summary.md", "eval.rrd", "triage.md", "triage.rrd", "compare.md", "compare.rrd", "table.md"):
        assert (run_dir / name).is_file(), name


def test_runs_script(kitti_root, tmp_path):
    proc = subprocess.run([sys.executable, str(EXAMPLES / "runs.py"), str(tmp_path)], capture_output=True, text=True,
                          cwd=tmp_path, env=_env(kitti_root), timeout=300)
    assert proc.returncode == 0, proc.stderr
    _runs_figures(proc.stdout, tmp_path / "run")


def test_runs_notebook_runs_headless(kitti_root, tmp_path):
    outputs = _run_notebook("runs.ipynb", kitti_root, tmp_path)
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    _runs_figures(text, tmp_path / "notebook_run")
