"""Shared fixtures. The real KITTI samples live beside the project (never inside it):
``$FVIZ_KITTI_ROOT``, default ``../shared/data/kitti``. Missing data skips locally and fails in CI."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
from hypothesis import settings

PROJECT = Path(__file__).resolve().parents[1]


# CI runs the same property-test examples every time (a failure there is reproducible, never a draw of luck);
# local runs keep exploring new ones.
settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI", "").lower() == "true":
    settings.load_profile("ci")

# A suite started in the background by a shell without job control (`cmd &` in a script) inherits SIGINT
# ignored, and so would every fviz it starts: the Ctrl-C tests would wait on a process that cannot hear them.
# The children of this process get the default disposition back (a handler is reset at exec; an ignore is not).
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# One test process per core already (pytest-xdist): OpenMP, BLAS and OpenCV threads in each, and in every fviz
# they start, would only wait on each other (~5-10 % of the suite's CPU). A user's setting is kept.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM"):
    os.environ.setdefault(_var, "1")


def _kitti_root() -> Path:
    return Path(os.environ.get("FVIZ_KITTI_ROOT", PROJECT.parent / "shared" / "data" / "kitti"))


@pytest.fixture(scope="session")
def kitti_root() -> Path:
    root = _kitti_root()
    if not (root / "odometry" / "dataset" / "sequences" / "00" / "calib.txt").is_file():
        msg = f"KITTI sample data missing at {root} (set FVIZ_KITTI_ROOT)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    return root


def _strecha_root() -> Path:
    return Path(os.environ.get("FVIZ_STRECHA_ROOT", PROJECT.parent / "shared" / "data" / "strecha"))


@pytest.fixture(scope="session")
def strecha_root() -> Path:
    """The Strecha fountain-P11 sample (``$FVIZ_STRECHA_ROOT``, default ``../shared/data/strecha``): skipped when
    missing locally, a failure in CI."""
    root = _strecha_root()
    if not (root / "fountain-P11" / "pairs_with_gt.txt").is_file():
        msg = f"Strecha sample data missing at {root} (set FVIZ_STRECHA_ROOT)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    return root


@pytest.fixture(scope="session")
def odometry(kitti_root):
    from fviz.data.kitti import open_dataset

    return open_dataset(kitti_root, sequence="00")


@pytest.fixture(scope="session")
def raw_drive(kitti_root):
    from fviz.data.kitti import open_dataset

    return open_dataset(kitti_root, drive="2011_09_26_drive_0001")


@pytest.fixture(scope="module")
def torch_one_thread():
    """One torch thread: on a shared CPU, OpenMP threads waiting on each other make tiny models 10-40x slower."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
