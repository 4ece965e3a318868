"""Run the real ``fviz`` command line in a subprocess, as a user would."""

import csv
import subprocess
import sys


# The smallest network a recipe can name (seconds to train on a CPU): the [model] table of test recipes.
TINY_MODEL_TOML = """[model]
variant = "siamese-rec-pos-fbn"
input_size = [32, 96]
width = 8
hidden = 16
pool_grid = [2, 4]
"""


def synthetic_recipe(path, out_dir, extra: str = ""):
    """A recipe training the tiny network on 8 synthetic pairs (4 held out), batches of 4, into ``out_dir``;
    ``extra``: more lines of its [train] table. -> path."""
    path.write_text(f"""{TINY_MODEL_TOML}[data]
source = "synthetic"
train_size = 8
val_size = 4
[train]
batch_size = 4
epochs = 5
num_workers = 0
out_dir = "{out_dir}"
{extra}""")
    return path


def run_fviz(*args, cwd=None, timeout=120):
    return subprocess.run([sys.executable, "-m", "fviz", *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=timeout)


def assert_one_line_error(proc, code, *fragments):
    assert proc.returncode == code, proc.stderr
    err = proc.stderr.strip().splitlines()
    assert "Traceback" not in proc.stderr
    assert len(err) == 1 and err[0].startswith("error: "), proc.stderr
    for f in fragments:
        assert f in err[0], err[0]


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
