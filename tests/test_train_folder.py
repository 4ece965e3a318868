"""A training's folder: held like eval's (a second training into it is refused), never written through a planted
link, its model never overwritten, its checkpoints checked and kept whole (a bit flip, a full disk, a resume keeping
its files' modes); a training that would fail at its end or on its recipe fails at its start."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from cli_util import TINY_MODEL_TOML, assert_one_line_error, run_fviz, synthetic_recipe



PROJECT = Path(__file__).resolve().parents[1]


def ok(*args, **kw):
    r = run_fviz(*args, **kw)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return r


# ------------------------------------------------------------------------------ held and refused before training


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


# ------------------------------------------------------------------------------ a trained model and its checkpoints


def train_recipe(tmp_path, out_dir, steps=2):
    return synthetic_recipe(tmp_path / "r.toml", out_dir, f"max_steps = {steps}\nthreads = 1\n")


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A finished tiny training (recipe, out_dir)."""
    base = tmp_path_factory.mktemp("train")
    out = base / "out"
    recipe = train_recipe(base, out)
    ok("train", recipe)
    return recipe, out


def test_train_never_overwrites_a_model_whose_last_pt_was_removed(trained, tmp_path):
    _, done = trained
    out = tmp_path / "out"
    shutil.copytree(done, out)
    (out / "last.pt").unlink()
    kept = (out / "model.pt").read_bytes()
    r = run_fviz("train", train_recipe(tmp_path, out))
    assert_one_line_error(r, 2, f"{out} already holds a trained model (model.pt, without last.pt")
    assert (out / "model.pt").read_bytes() == kept


def test_a_bit_flipped_checkpoint_is_refused(trained, tmp_path):
    import torch

    _, done = trained
    model = tmp_path / "model.pt"
    shutil.copy(done / "model.pt", model)
    ckpt = torch.load(model, weights_only=True)
    assert "state_digest" in ckpt
    # flip one bit of the largest tensor's bytes inside the file (the zip stores tensors uncompressed)
    name, tensor = max(ckpt["model_state"].items(), key=lambda kv: kv[1].numel())
    raw = bytearray(model.read_bytes())
    needle = tensor.contiguous().view(torch.uint8).numpy().tobytes()[:64]
    at = raw.find(needle)
    assert at > 0, "tensor bytes not found in the file"
    raw[at + 5] ^= 0x10
    model.write_bytes(bytes(raw))
    from fviz.errors import FvizError
    from fviz.models.weights import load_model

    with pytest.raises(FvizError, match="damaged: its weights do not match the digest"):
        load_model(model)
    r = run_fviz("inspect", "pair", "--synthetic", "--seed", "0", "-e", f"deep:{model}", "--out", tmp_path / "x.rrd")
    assert r.returncode == 2 and "damaged" in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_a_planted_model_pt_link_out_of_the_train_folder_is_never_written_through(tmp_path):
    out, victim = tmp_path / "out", tmp_path / "victim.pt"
    out.mkdir()
    victim.write_bytes(b"precious")
    (out / "model.pt").symlink_to(victim)
    r = run_fviz("train", train_recipe(tmp_path, out))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert victim.read_bytes() == b"precious"
    # a link at train.rrd: refused before training, its target untouched
    out2 = tmp_path / "out2"
    out2.mkdir()
    (out2 / "train.rrd").symlink_to(victim)
    assert_one_line_error(run_fviz("train", train_recipe(tmp_path, out2)), 2, "train.rrd is a symlink to", "outside")
    assert victim.read_bytes() == b"precious"


def test_a_resumed_train_keeps_a_600_train_rrd(trained, tmp_path):
    recipe, done = trained
    out = tmp_path / "out"
    shutil.copytree(done, out)
    for name in ("train.rrd", "last.pt"):
        os.chmod(out / name, 0o600)
    ok("train", train_recipe(tmp_path, out, steps=3), "--resume")
    for name in ("train.rrd", "last.pt", "model.pt"):
        assert stat.S_IMODE(os.stat(out / name).st_mode) in (0o600,) or name == "model.pt", name
    assert not list(out.glob(".*tmp*"))


def _limit_file_size(limit):
    def pre():
        import resource
        import signal

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # write() then fails with EFBIG instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return pre


def test_disk_full_while_train_writes_a_checkpoint_is_one_line(tmp_path):
    """Simulated with RLIMIT_FSIZE (a tmpfs needs mount rights the test runner may lack): write() fails with EFBIG."""
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "fviz", "train", str(train_recipe(tmp_path, out))], capture_output=True,
                       text=True, timeout=600, preexec_fn=_limit_file_size(20_000))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    last = r.stderr.strip().splitlines()[-1]  # after training's own progress lines
    assert last.startswith("error: cannot write") and "last.pt" in last and "previous version is kept" in last, last
    # nothing half-written is left (a run that saved nothing leaves no folder at all)
    assert not out.exists() or not [p for p in out.iterdir() if ".tmp" in p.name], list(out.iterdir())


def test_an_input_size_too_small_names_the_recipe_key(tmp_path):
    recipe = train_recipe(tmp_path, tmp_path / "out")
    r = run_fviz("train", recipe, "--set", "model.input_size=[16, 40]")
    assert_one_line_error(r, 2, f"recipe {recipe}", "model.input_size [16, 40]: the synthetic scenes need a height (H) "
                          "of 32 to 8192 pixels, got 16")
    assert not (tmp_path / "out").exists()
