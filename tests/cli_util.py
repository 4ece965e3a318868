"""Run the real ``fviz`` command line in a subprocess, as a user would."""

import csv
import subprocess
import sys


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
