"""``fviz eval`` under real signals, in real subprocesses: SIGTERM acts as Ctrl-C, SIGKILL of the main
process takes its workers with it, a hanging estimator cannot hold the run, a crashing worker fails
only its pair. Every wait polls for a condition (no fixed sleeps)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_util import read_csv

pytestmark = [pytest.mark.kitti, pytest.mark.slow]

PROJECT = Path(__file__).resolve().parents[1]
SMALL = ("-e", "8point", "--features", "orb", "--max-keypoints", "400", "--no-progress")


def start_eval(kitti_root, out, frames, *extra, workers=2, pythonpath=()):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([*map(str, pythonpath), str(PROJECT), os.environ.get("PYTHONPATH", "")]))
    err = open(out.parent / "stderr.txt", "w")
    args = ["--kitti-root", str(kitti_root), "--sequence", "00", "--pair", "temporal", "--frames", frames,
            "--workers", str(workers), "--out-dir", str(out), *extra]
    proc = subprocess.Popen([sys.executable, "-m", "fviz", "eval", *args], stdout=subprocess.DEVNULL, stderr=err, env=env)
    return proc, out.parent / "stderr.txt"


def poll(condition, proc=None, timeout=180, what="condition"):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if condition():
            return
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the run ended (exit {proc.returncode}) before: {what}")
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for: {what}")


def lines(path):
    return sum(1 for _ in open(path)) if path.is_file() else 0


def children(pid):
    """Child pids of ``pid`` (Linux /proc)."""
    out = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        text = (task / "children").read_text()
        out |= {int(p) for p in text.split()}
    return out


def alive(pid):
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


def workers_of(proc, n):
    found = set()

    def enough():
        found.update(children(proc.pid))
        return len(found) >= n

    poll(enough, proc, what=f"{n} worker processes")
    return found


def test_sigterm_stops_like_ctrl_c_and_writes_the_reports(kitti_root, tmp_path):
    out = tmp_path / "run"
    proc, err = start_eval(kitti_root, out, "0:40", *SMALL)
    workers = workers_of(proc, 2)
    poll(lambda: lines(out / "results.jsonl") >= 3, proc, what="3 finished pairs")
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=120) == 130
    text = err.read_text()
    assert "Traceback" not in text and "SIGTERM" in text and "--resume" in text
    done = [json.loads(line) for line in open(out / "results.jsonl")]
    assert 3 <= len(done) < 39
    assert {r["name"] for r in read_csv(out / "metrics.csv")} == {r["key"] for r in done}
    assert (out / "summary.md").is_file() and (out / "eval.rrd").is_file()
    poll(lambda: not any(alive(p) for p in workers), what="the workers to exit")


def test_sigkill_of_the_main_process_takes_its_workers_with_it(kitti_root, tmp_path):
    out = tmp_path / "run"
    proc, _ = start_eval(kitti_root, out, "0:40", *SMALL)
    workers = workers_of(proc, 2)
    poll(lambda: lines(out / "results.jsonl") >= 1, proc, what="a finished pair")
    proc.kill()
    proc.wait(timeout=30)
    poll(lambda: not any(alive(p) for p in workers), timeout=60, what="the orphaned workers to die")


HANG = """
import os, time
import cv2

def hang(pair, x_a, x_b):
    if pair.id.frame_a == 2:
        open(os.environ["HANG_MARK"], "w").close()
        while True:
            try:
                time.sleep(3600)
            except {swallowed}:
                pass
    return cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)[0]
"""


def _hanging_run(kitti_root, tmp_path, workers, swallowed):
    (tmp_path / "hang_est.py").write_text(HANG.format(swallowed=swallowed))
    os.environ["HANG_MARK"] = str(tmp_path / "hanging")
    try:
        proc, err = start_eval(kitti_root, tmp_path / "run", "0:12", "-e", "hang_est:hang", *SMALL[2:],
                               workers=workers, pythonpath=[tmp_path])
    finally:
        del os.environ["HANG_MARK"]
    poll(lambda: (tmp_path / "hanging").exists(), proc, what="the estimator to hang")
    return proc, err


def interrupt(proc, err, times):
    """Send SIGINT ``times`` times, each once the previous one was acknowledged on stderr."""
    for n in range(times):
        before = err.read_text().count("SIGINT:")
        proc.send_signal(signal.SIGINT)
        poll(lambda: err.read_text().count("SIGINT:") > before or proc.poll() is not None, what=f"interrupt {n + 1} acknowledged")


@pytest.mark.parametrize("workers", [1, 2])
def test_a_hanging_estimator_is_abandoned_at_the_second_interrupt(kitti_root, tmp_path, workers):
    proc, err = _hanging_run(kitti_root, tmp_path, workers, "ZeroDivisionError")
    children_before = children(proc.pid)
    interrupt(proc, err, 2)
    assert proc.wait(timeout=120) == 130
    text = err.read_text()
    assert "stopping after the pairs in flight" in text and "abandoning" in text and "Traceback" not in text
    results = tmp_path / "run" / "results.jsonl"  # on a loaded machine the other pair may not have finished either
    done = [json.loads(line) for line in open(results)] if results.is_file() else []
    assert "odometry/00/temporal/f000002c0-f000003c0" not in {r["key"] for r in done}
    assert {r["name"] for r in read_csv(tmp_path / "run" / "metrics.csv")} == {r["key"] for r in done}
    poll(lambda: not any(alive(p) for p in children_before), what="the workers to exit")


def test_the_third_interrupt_ends_a_run_whose_estimator_swallows_them(kitti_root, tmp_path):
    proc, err = _hanging_run(kitti_root, tmp_path, 1, "BaseException")
    interrupt(proc, err, 3)
    assert proc.wait(timeout=60) == 130
    assert "interrupted three times" in err.read_text()


def test_a_worker_that_dies_fails_its_pair_and_the_run_goes_on(kitti_root, tmp_path):
    (tmp_path / "crash_est.py").write_text(
        "import os, signal, cv2\n"
        "def crash(pair, x_a, x_b):\n"
        "    if pair.id.frame_a == 4:\n"
        "        os.kill(os.getpid(), signal.SIGKILL)\n"
        "    return cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)[0]\n"
    )
    out = tmp_path / "run"
    proc, err = start_eval(kitti_root, out, "0:12", "-e", "crash_est:crash", *SMALL[2:], pythonpath=[tmp_path])
    assert proc.wait(timeout=300) == 0, err.read_text()
    records = {r["key"]: r for r in map(json.loads, open(out / "results.jsonl"))}
    assert len(records) == 11
    failed = {k for k, r in records.items() if r["error"]}
    assert failed == {"odometry/00/temporal/f000004c0-f000005c0"}
    assert "died" in records["odometry/00/temporal/f000004c0-f000005c0"]["error"]
    assert len(read_csv(out / "metrics.csv")) == 11 * 2
