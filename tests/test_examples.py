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


def _run_notebook(name: str, kitti_root, out) -> list:
    """Execute ``examples/NAME`` headless (its kernel inherits FVIZ_OUT=out and the KITTI root) -> its code cells' outputs."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    nb = nbformat.read(EXAMPLES / name, as_version=4)
    env_before = dict(os.environ)
    os.environ.update(_env(kitti_root, FVIZ_OUT=str(out)))
    try:
        nbclient.NotebookClient(nb, kernel_name="python3", timeout=300, resources={"metadata": {"path": str(EXAMPLES)}}).execute()
    finally:
        os.environ.clear()
        os.environ.update(env_before)
    return [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]


def test_notebook_runs_headless(kitti_root, tmp_path):
    outputs = _run_notebook("quickstart.ipynb", kitti_root, tmp_path)
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    sed = _sed_rows(text)
    assert list(sed) == ["gt", "magsac", "mine"] and sed["magsac"] < 0.5 < sed["mine"]
    assert f"saved {tmp_path / 'notebook_pair.rrd'}" in text and (tmp_path / "notebook_pair.rrd").is_file()
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
