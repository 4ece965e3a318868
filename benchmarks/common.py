"""Shared by the benchmark scripts: where the data is, and timing of whole commands."""

import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

PROJECT = Path(__file__).resolve().parents[1]
KITTI_ROOT = Path(os.environ.get("FVIZ_KITTI_ROOT", PROJECT.parent / "shared" / "data" / "kitti"))


def wall(cmd: list[str], repeat: int = 3, **kw) -> float:
    """Median wall time (s) of a command run ``repeat`` times; raises if it fails."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, **kw)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def python(code: str) -> list[str]:
    return [sys.executable, "-c", code]
