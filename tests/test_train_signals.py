"""``fviz train`` as a user runs it: real subprocesses, real signals, real files."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from cli_util import TINY_MODEL_TOML, assert_one_line_error, run_fviz

from fviz.models import FNet
from fviz.train.checkpoint import save_checkpoint

TINY = TINY_MODEL_TOML + """dropout = 0.0
[data]
source = "synthetic"
train_size = 100000
val_size = 4
val_points = 16
[train]
batch_size = 2
epochs = 1
max_steps = 100000
num_workers = 0
log_every = 1
checkpoint_every = 5
val_every = 0
out_dir = "{out}"
"""


def _recipe(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(TINY.format(out=tmp_path / "out"))
    return path


def _start(recipe: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "fviz", "train", str(recipe), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float = 240.0) -> None:
    """Until ``path`` exists (the run has written its first checkpoint); fails if the run ends first."""
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.2)


def _step(path: Path) -> int:
    from fviz.train.checkpoint import read_checkpoint

    return int(read_checkpoint(path)["step"])


def _curve_steps(path: Path) -> list[int]:
    from fviz.record.reader import _chunks, _index_names, _ints

    return sorted(s for ent, _, rb in _chunks(path) if ent == "train/loss" and "step" in _index_names(rb)
                  for s in _ints(rb.column("step")))


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_saves_a_checkpoint_and_prints_the_resume_command(tmp_path, sig):
    recipe = _recipe(tmp_path)
    out = tmp_path / "out"
    proc = _start(recipe, "--set", "train.lr=5e-4")
    _wait_for(out / "last.pt", proc)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert f"interrupted ({sig.name}) at step" in stderr
    resume = next(ln for ln in lines if ln.startswith("continue with: "))[len("continue with: "):]
    assert resume == f"fviz train {recipe} --set train.lr=5e-4 --resume"
    step = _step(out / "last.pt")
    assert step >= 5 and f"at step {step}:" in stderr  # the checkpoint holds the step the message names
    assert _curve_steps(out / "train.rrd") == list(range(1, step + 1))  # complete, readable curves
    assert not [p.name for p in out.iterdir() if p.name not in ("last.pt", "train.rrd")]
    # the printed command continues (a shorter run here: a later --set wins)
    args = resume.split()[2:] + ["--set", f"train.max_steps={step + 3}"]
    done = run_fviz("train", *args, timeout=240)
    assert done.returncode == 0, done.stderr
    assert _step(out / "last.pt") == step + 3 and (out / "model.pt").is_file()
    assert _curve_steps(out / "train.rrd") == list(range(1, step + 4))


def test_sigkill_leaves_a_readable_recording_and_resume_repairs_it(tmp_path):
    recipe = _recipe(tmp_path)
    out = tmp_path / "out"
    proc = _start(recipe)
    _wait_for(out / "train.rrd", proc)
    proc.kill()
    proc.communicate(timeout=60)
    summary = run_fviz("summary", out / "train.rrd")
    assert summary.returncode == 0 and "truncated" not in summary.stdout + summary.stderr, summary.stderr
    step = _step(out / "last.pt")
    assert not list(out.glob("*.part"))
    # a recording left by a version that streamed into train.rrd.part is cleaned up by --resume
    (out / "train.rrd.part").write_bytes(b"stale")
    done = run_fviz("train", recipe, "--set", f"train.max_steps={step + 2}", "--resume", timeout=240)
    assert done.returncode == 0, done.stderr
    assert _curve_steps(out / "train.rrd") == list(range(1, step + 3))
    assert not list(out.glob("*.part")) and not list(out.glob(".*tmp*"))


def test_bad_recipe_values_are_one_line_errors(tmp_path):
    recipe = _recipe(tmp_path)
    assert_one_line_error(run_fviz("train", recipe, "--set", "train.lr=nan"), 2, "train.lr", "finite")
    (tmp_path / "a-file").write_text("x")
    assert_one_line_error(run_fviz("train", recipe, "--set", f"train.out_dir={tmp_path / 'a-file'}"), 2,
                          "train.out_dir", "a-file", "not a folder")
    assert_one_line_error(run_fviz("train", recipe, "--set", "model.width=-5"), 2, "model.width", "-5")


def _tiny_model(width: int = 8) -> FNet:
    return FNet.from_variant("siamese-rec-pos-fbn", input_hw=(32, 96), width=width, hidden=16, pool_grid=(2, 4))


def test_checkpoint_errors_are_complete_sentences(tmp_path):
    good = save_checkpoint(tmp_path / "good.pt", _tiny_model())
    ck = torch.load(good, weights_only=True)
    ck.pop("state_digest")  # files made by hand (or by fviz before the digest): their content is checked field by field

    bad_config = tmp_path / "bad-config.pt"
    torch.save({**ck, "model_config": {**ck["model_config"], "width": -5}}, bad_config)
    assert_one_line_error(run_fviz("inspect", "pair", "--synthetic", "-e", f"deep:{bad_config}"), 2,
                          "bad-config.pt", "width must be >= 1, got -5")

    mismatch = tmp_path / "mismatch.pt"
    torch.save({**ck, "model_state": _tiny_model(width=16).state_dict()}, mismatch)
    proc = run_fviz("inspect", "pair", "--synthetic", "-e", f"deep:{mismatch}")
    assert_one_line_error(proc, 2, "mismatch.pt", "siamese-rec-pos-fbn (width 8", "(16, ", "(8, ", "in the file vs expected")

    pickled = tmp_path / "pickled.pt"
    torch.save({"format": "fviz-fnet", "model": Path("x")}, pickled)  # an object weights_only refuses
    proc = run_fviz("inspect", "pair", "--synthetic", "-e", f"deep:{pickled}")
    assert_one_line_error(proc, 2, "pickled.pt", "holds Python objects other than tensors")
    assert "weights_only" not in proc.stderr and proc.stderr.strip().endswith(")")

    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[:1000])
    proc = run_fviz("inspect", "pair", "--synthetic", "-e", f"deep:{truncated}")
    assert_one_line_error(proc, 2, "truncated.pt", "not a torch file, or it is truncated")

    folder = tmp_path / "folder.pt"
    folder.mkdir()
    assert_one_line_error(run_fviz("inspect", "pair", "--synthetic", "-e", f"deep:{folder}"), 2, "folder.pt", "is a folder")


def test_deep_synthetic_is_the_synthetic_only_model(tmp_path):
    import json

    proc = run_fviz("inspect", "pair", "--synthetic", "--seed", "4", "-e", "deep", "-e", "deep:synthetic",
                    "--out", tmp_path / "x.rrd", "--json")
    assert proc.returncode == 0, proc.stderr
    names = [e["name"] for e in json.loads(proc.stdout)["estimators"]]
    assert names == ["gt", "deep", "deep-synthetic"]
    manifest = json.loads((Path(__file__).resolve().parents[1] / "assets" / "MANIFEST.json").read_text())
    assert "no KITTI image" in manifest["data"] or os.path.exists(Path(__file__).resolve().parents[1] / "assets" / "fviz-deep-synthetic.pt")
