"""Files fviz writes (issue 17): temporaries that cannot be planted, permissions kept on replace, and
training's out_dir held like eval's; a training that would fail at its end fails at its start."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from cli_util import TINY_MODEL_TOML, run_fviz

from fviz import atomic



PROJECT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------ atomic replace


def test_a_symlink_planted_at_the_old_temporary_name_is_not_written_through(tmp_path):
    victim, out = tmp_path / "victim", tmp_path / "report.csv"
    victim.write_text("precious\n")
    (tmp_path / f".report.csv.tmp{os.getpid()}").symlink_to(victim)  # the name fviz used to write to
    atomic.write_text(out, "a,b\n")
    assert out.read_text() == "a,b\n" and victim.read_text() == "precious\n"
    assert not out.is_symlink()


def test_temporaries_are_new_unpredictable_files_beside_the_target(tmp_path):
    out = tmp_path / "report.csv"
    with atomic.replacing(out) as a, atomic.replacing(out) as b:
        assert a != b and a.parent == b.parent == tmp_path
        assert a.is_file() and not a.is_symlink() and stat.S_IMODE(a.stat().st_mode) == 0o600
        a.write_text("1")
        b.write_text("2")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.csv"]


@pytest.mark.parametrize("mode", [0o600, 0o640, 0o664])
def test_replacing_a_file_keeps_its_mode(tmp_path, mode):
    out = tmp_path / "report.csv"
    out.write_text("old\n")
    os.chmod(out, mode)
    atomic.write_text(out, "new\n")
    assert out.read_text() == "new\n" and stat.S_IMODE(out.stat().st_mode) == mode


def test_a_new_file_gets_the_umask_mode(tmp_path):
    old = os.umask(0o027)
    try:
        atomic.write_text(tmp_path / "new.csv", "x\n")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "new.csv").stat().st_mode) == 0o640


# ------------------------------------------------------------------------------ training


def tiny_recipe(tmp_path: Path, out_dir: Path, **train) -> Path:
    extra = "".join(f"{k} = {v}\n" for k, v in train.items())
    recipe = tmp_path / "tiny.toml"
    recipe.write_text(f"""{TINY_MODEL_TOML}[data]
source = "synthetic"
train_size = 4
val_size = 2
val_points = 16
[train]
batch_size = 2
max_steps = 1
num_workers = 0
out_dir = "{out_dir}"
{extra}""")
    return recipe


def only_error_line(proc) -> str:
    """The one ``error:`` line of a failed command (training prints its banner on stderr before)."""
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, proc.stderr
    return errors[0]


def test_a_second_training_into_a_held_out_dir_is_refused(tmp_path):
    out, go = tmp_path / "run", tmp_path / "go"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time, pathlib\nfrom fviz.lock import locked\n"
         "with locked(sys.argv[1], 'train.out_dir'):\n    print('held', flush=True)\n"
         "    while not pathlib.Path(sys.argv[2]).exists(): time.sleep(0.02)\n", str(out), str(go)],
        stdout=subprocess.PIPE, text=True, cwd=PROJECT)
    try:
        assert holder.stdout.readline().strip() == "held"
        line = only_error_line(run_fviz("train", tiny_recipe(tmp_path, out)))
        assert f"train.out_dir {out} is in use by pid {holder.pid}" in line
        assert not (out / "model.pt").exists() and not (out / "last.pt").exists()
    finally:
        go.touch()
        holder.wait(timeout=60)


def test_a_folder_where_train_rrd_goes_is_refused_before_training(tmp_path):
    out = tmp_path / "run"
    (out / "train.rrd").mkdir(parents=True)
    line = only_error_line(run_fviz("train", tiny_recipe(tmp_path, out)))
    assert "train.rrd" in line and "a folder" in line
    assert not (out / "last.pt").exists()


@pytest.mark.kitti
def test_a_corrupt_training_image_with_loader_workers_is_one_line(kitti_root, tmp_path):
    src = kitti_root / "odometry" / "dataset"
    root = tmp_path / "kitti"
    for seq in ("02", "10"):
        d = root / "odometry" / "dataset" / "sequences" / seq
        (d / "image_2").mkdir(parents=True)
        shutil.copy(src / "sequences" / seq / "calib.txt", d)
        for png in sorted((src / "sequences" / seq / "image_2").glob("*.png")):
            (d / "image_2" / png.name).symlink_to(png)
    (root / "odometry" / "dataset" / "poses").mkdir()
    for seq in ("02", "10"):
        shutil.copy(src / "poses" / f"{seq}.txt", root / "odometry" / "dataset" / "poses")
    bad = root / "odometry" / "dataset" / "sequences" / "02" / "image_2" / "000001.png"
    bad.unlink()
    bad.write_bytes(b"not a png")
    recipe = tmp_path / "k.toml"
    recipe.write_text(
        f'data = {{ source = "kitti-odometry", root = "{root}", sequences = ["02"], val_sequences = ["10"], '
        f'cameras = [2], frames = [0, 4] }}\n'
        f'train = {{ batch_size = 2, max_steps = 2, num_workers = 1, out_dir = "{tmp_path / "run"}" }}\n'
        + TINY_MODEL_TOML)
    proc = run_fviz("train", recipe, timeout=600)
    assert only_error_line(proc) == f"error: unreadable or corrupt image: {bad}"
    assert "DataLoader" not in proc.stderr
