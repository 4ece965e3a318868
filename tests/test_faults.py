"""Nothing lost: special files as --out, two runs into one folder, Ctrl-C while reports are written, a full
disk. Real ``fviz`` subprocesses, real signals and real files; a run is held at a known point by a user
estimator waiting on a file (faults/fault_estimators.py) or an audit hook pausing one ``open`` call
(faults/pause_on_open.py), never by sleeping and hoping."""

from __future__ import annotations

import json
import os
import signal
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_util import assert_one_line_error, read_csv, run_fviz

from fviz.record.reader import open_rrd
from fviz.record.summary import read_recording

FAULTS = Path(__file__).parent / "faults"
SMALL = ("--max-keypoints", "400", "--no-progress", "--workers", "1")
SYNTHETIC = ("--synthetic", "--seeds", "0:3", "--pair", "stereo", *SMALL)
INSPECT = ("inspect", "pair", "--synthetic", "--seed", "0", "-e", "8point")


def fviz_env(**extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(FAULTS), env.get("PYTHONPATH", "")) if p)
    env.update(extra)
    return env


def fviz(*args, env=None, file_size_limit=None, timeout=300) -> subprocess.CompletedProcess:
    """``fviz ARGS``, finished; ``file_size_limit``: bytes a file may grow to (past it a write fails with EFBIG,
    SIGXFSZ ignored, as a full disk fails with ENOSPC)."""
    return run_fviz(*args, env=env or fviz_env(), file_size_limit=file_size_limit, timeout=timeout)


def start(*args, env, prefix=("-m", "fviz")) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, *prefix, *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)


def wait_for(condition, proc: subprocess.Popen, what: str, timeout: float = 300) -> None:
    """Poll ``condition`` (generous budget); fail early if ``proc`` exits first."""
    end = time.monotonic() + timeout
    while not condition():
        if proc.poll() is not None:
            out, err = proc.communicate()
            raise AssertionError(f"exited {proc.returncode} before {what}: {err}")
        assert time.monotonic() < end, f"no {what} within {timeout} s"
        time.sleep(0.02)


def leftovers(folder: Path) -> list[str]:
    """Temporary files fviz would leave behind."""
    return sorted(p.name for p in Path(folder).rglob("*") if ".tmp" in p.name)


def held_run(tmp_path: Path, out: Path, *extra: str) -> tuple[subprocess.Popen, Path, Path]:
    """A real ``fviz eval`` into ``out`` that waits inside its first pair until ``go`` exists."""
    inside, go = tmp_path / "inside", tmp_path / "go"
    proc = start("eval", *SYNTHETIC, "-e", "8point", "-e", "fault_estimators:held", "--out-dir", out, *extra,
                 env=fviz_env(FVIZ_TEST_INSIDE=str(inside), FVIZ_TEST_GO=str(go)))
    wait_for(inside.exists, proc, "the held pair")
    return proc, inside, go


# ------------------------------------------------------------------------------ special files as --out


def test_out_through_a_symlink_replaces_its_target(tmp_path):
    target = tmp_path / "real" / "pair.rrd"
    target.parent.mkdir()
    target.write_text("old")
    link = tmp_path / "link.rrd"
    link.symlink_to(target)
    r = fviz(*INSPECT, "--out", link)
    assert r.returncode == 0, r.stderr
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert read_recording(target).items[0].name is not None  # the target is now the complete recording
    assert leftovers(tmp_path) == []


def _special(kind: str, path: Path) -> None:
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "device":
        try:
            os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))  # what /dev/null is
        except PermissionError:
            pytest.skip("mknod not permitted here (needs root)")
    elif kind == "folder":
        path.mkdir()
        (path / "keep.txt").write_text("mine")
    elif kind == "socket":
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(path))
        s.close()


@pytest.mark.parametrize("kind, said", [("fifo", "a FIFO"), ("device", "a character device"), ("folder", "a folder"),
                                        ("socket", "a socket")])
@pytest.mark.parametrize("via_link", [False, True])
def test_out_never_replaces_a_special_file(tmp_path, kind, said, via_link):
    node = tmp_path / "node.rrd"
    _special(kind, node)
    before = os.lstat(node)
    out = node
    if via_link:
        out = tmp_path / "link.rrd"
        out.symlink_to(node)
    r = fviz(*INSPECT, "--out", out)
    assert_one_line_error(r, 2, str(out), said, "not a regular file")
    after = os.lstat(node)
    assert (stat.S_IFMT(after.st_mode), after.st_ino) == (stat.S_IFMT(before.st_mode), before.st_ino)
    if kind == "folder":
        assert sorted(p.name for p in node.iterdir()) == ["keep.txt"]
    assert leftovers(tmp_path) == []


# ------------------------------------------------------------------------------ run folder lock


def test_a_second_run_into_a_held_folder_is_refused_naming_the_holder(tmp_path):
    out = tmp_path / "run"
    holder, _, go = held_run(tmp_path, out)
    try:
        for args in (("eval", *SYNTHETIC, "-e", "8point", "--threshold", "3", "--out-dir", out),
                     ("triage", "--out-dir", out, "--no-progress")):
            r = fviz(*args)
            assert_one_line_error(r, 2, f"--out-dir {out} is in use by pid {holder.pid} on {socket.gethostname()}",
                                  "since", "(fviz eval ")
        go.touch()
        _, err = holder.communicate(timeout=300)
    finally:
        go.touch()
        holder.kill()
    assert holder.returncode == 0, err
    assert json.loads((out / "run.json").read_text())["options"]["threshold"] == 1.0  # the holder's run, unmixed
    records = [json.loads(line) for line in open(out / "results.jsonl")]
    assert sorted(r["index"] for r in records) == [0, 1, 2]  # each pair once
    assert not (out / ".fviz.lock").exists()


def test_the_lock_of_a_killed_run_is_recovered(tmp_path):
    out = tmp_path / "run"
    holder, _, go = held_run(tmp_path, out)
    holder.kill()
    holder.communicate(timeout=60)
    assert json.loads((out / ".fviz.lock").read_text())["pid"] == holder.pid  # left behind by SIGKILL
    go.touch()
    r = fviz("eval", *SYNTHETIC, "-e", "8point", "-e", "fault_estimators:held", "--out-dir", out,
             env=fviz_env(FVIZ_TEST_INSIDE=str(tmp_path / "inside"), FVIZ_TEST_GO=str(go)))
    assert r.returncode == 0, r.stderr
    assert f"recovered the lock left by pid {holder.pid}" in r.stderr and "Traceback" not in r.stderr
    assert len(read_csv(out / "metrics.csv")) == 3 * 3  # gt, 8point, held per pair
    assert not (out / ".fviz.lock").exists()


# ------------------------------------------------------------------------------ Ctrl-C


def test_ctrl_c_while_the_reports_are_written_keeps_the_previous_recording(tmp_path):
    out = tmp_path / "run"
    args = ("eval", *SYNTHETIC, "-e", "8point", "--full", "--out-dir", out)
    assert fviz(*args).returncode == 0
    complete = (out / "eval.rrd").read_bytes()
    assert len(read_recording(out / "eval.rrd").items) == 3
    paused, resume = tmp_path / "paused", tmp_path / "resume"
    # Held while eval.rrd is half written: when the report writer opens the second pair's payload.
    proc = start(*args, "--resume", prefix=("-c", "import pause_on_open"),
                 env=fviz_env(FVIZ_PAUSE_ON="pairs/000001.npz", FVIZ_PAUSED=str(paused), FVIZ_RESUME=str(resume)))
    try:
        wait_for(paused.exists, proc, "the report writer's pause")
        assert [p.name for p in out.glob(".eval.rrd.tmp*")]  # the new recording is being written
        # the first Ctrl-C lets the reports finish (and says so); the second stops them
        proc.send_signal(signal.SIGINT)
        first = ""
        while not first.strip():  # the notice starts on a new line
            first = proc.stderr.readline()
        assert "finishing the reports first (interrupt again to stop)" in first, first
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        resume.touch()
        proc.kill()
    assert proc.returncode == 130, err
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert "Traceback" not in err, err
    assert "stopping the reports; the previous versions stay" in lines[0], err
    assert len(lines) == 2 and lines[1].startswith("interrupted: while writing the reports: "), err
    assert "eval.rrd kept its previous version" in lines[1] and f"fviz eval --out-dir {out} --resume" in lines[1]
    assert (out / "eval.rrd").read_bytes() == complete  # the complete recording, not a partial one
    assert leftovers(out) == []
    r = fviz("eval", "--out-dir", out, "--resume", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert len(read_recording(out / "eval.rrd").items) == 3


def test_ctrl_c_anywhere_says_what_was_kept(tmp_path):
    """Ctrl-C inside a command (here inspect, in an estimator): one line from fviz's entry point, exit 130."""
    inside, go, out = tmp_path / "inside", tmp_path / "go", tmp_path / "pair.rrd"
    out.write_bytes(b"previous")
    proc = start("inspect", "pair", "--synthetic", "--seed", "0", "-e", "fault_estimators:held", "--out", out,
                 env=fviz_env(FVIZ_TEST_INSIDE=str(inside), FVIZ_TEST_GO=str(go)))
    try:
        wait_for(inside.exists, proc, "the held estimator")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        go.touch()
        proc.kill()
    assert proc.returncode == 130
    assert err.strip().splitlines() == ["interrupted: nothing half-written was kept: a file being written was "
                                        "discarded, files already there are unchanged"]
    assert out.read_bytes() == b"previous"
    assert leftovers(tmp_path) == []


# ------------------------------------------------------------------------------ disk full


def _without_volatile(rows):
    return [{k: v for k, v in row.items() if k != "seconds"} for row in rows]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """A complete --full synthetic run: its files and their sizes."""
    out = tmp_path_factory.mktemp("reference") / "run"
    r = fviz("eval", *SYNTHETIC, "-e", "8point", "--full", "--out-dir", out)
    assert r.returncode == 0, r.stderr
    return out


def test_disk_full_mid_run_is_one_line_and_resume_finishes(reference, tmp_path):
    out = tmp_path / "run"
    lines = (reference / "results.jsonl").read_bytes().splitlines(keepends=True)
    limit = len(lines[0]) + len(lines[1]) // 2  # the second record does not fit (without --full's larger payloads)
    r = fviz("eval", *SYNTHETIC, "-e", "8point", "--out-dir", out, file_size_limit=limit)
    assert_one_line_error(r, 2, f"cannot write {out / 'results.jsonl'}: file too large",
                          f"fviz eval --out-dir {out} --resume")
    assert leftovers(out) == []
    r = fviz("eval", "--out-dir", out, "--resume", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert _without_volatile(read_csv(out / "metrics.csv")) == _without_volatile(read_csv(reference / "metrics.csv"))
    assert len(read_recording(out / "eval.rrd").items) == 3


def test_disk_full_while_writing_reports_keeps_the_previous_ones(reference, tmp_path):
    import shutil

    out = tmp_path / "run"
    shutil.copytree(reference, out)
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    # the feature cache (features.h5, matches.h5) is not rewritten by a resume that computes nothing
    small = max(p.stat().st_size for p in out.rglob("*") if p.is_file() and p.name not in ("eval.rrd", "features.h5", "matches.h5"))
    assert (out / "eval.rrd").stat().st_size > small + 4096  # only the recording outgrows the limit
    r = fviz("eval", "--out-dir", out, "--resume", "--no-progress", file_size_limit=small + 4096)
    assert_one_line_error(r, 2, f"cannot write {out / 'eval.rrd'}: file too large", "eval.rrd kept its previous version",
                          f"fviz eval --out-dir {out} --resume")
    assert (out / "eval.rrd").read_bytes() == before["eval.rrd"]
    open_rrd(out / "eval.rrd")
    assert leftovers(out) == []
    r = fviz("eval", "--out-dir", out, "--resume", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert len(read_recording(out / "eval.rrd").items) == 3


def test_a_full_tmpfs_is_one_line_and_leaves_no_temporaries(reference, tmp_path):
    """A real full disk (ENOSPC) on a small tmpfs, where mounting one is permitted (root)."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    size = (reference / "results.jsonl").stat().st_size + 64 * 1024
    if subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("mounting a tmpfs is not permitted here (needs root)")
    try:
        out = mnt / "run"
        r = fviz("eval", *SYNTHETIC, "-e", "8point", "--full", "--out-dir", out)
        assert r.returncode == 2, r.stderr
        err = r.stderr.strip().splitlines()
        assert len(err) == 1 and "Traceback" not in r.stderr and "disk full (No space left on device)" in err[0], r.stderr
        assert f"fviz eval --out-dir {out} --resume" in err[0]
        assert leftovers(out) == []
    finally:
        subprocess.run(["umount", str(mnt)], check=True)
