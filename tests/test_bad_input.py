"""Bad input (layouts, messages, bad numbers): every case through the real command line in a subprocess, on
real files. Each bad input is one line ``error: ...`` naming the file or flag, exit 2, no traceback, and
nothing written; a malformed results line or a user estimator returning junk loses nothing else."""

import json
import math
import os
import re
import shutil
import stat

import pytest
from cli_util import assert_one_line_error, read_csv, run_fviz

from fviz.estimators.deep import BUNDLED

pytestmark = pytest.mark.kitti

SMALL = ("--max-keypoints", "400", "--no-progress", "--features", "orb")
ROOT = os.geteuid() == 0 if hasattr(os, "geteuid") else False


def small_layout(tmp_path, kitti_root):
    """Odometry sequence 00 in tmp_path: frames 0-2 of camera 0 (links), copies of calib.txt and poses."""
    src = kitti_root / "odometry" / "dataset"
    seq = tmp_path / "kitti" / "dataset" / "sequences" / "00"
    (seq / "image_0").mkdir(parents=True)
    for f in range(3):
        (seq / "image_0" / f"{f:06d}.png").symlink_to(src / "sequences" / "00" / "image_0" / f"{f:06d}.png")
    shutil.copy(src / "sequences" / "00" / "calib.txt", seq / "calib.txt")
    (tmp_path / "kitti" / "dataset" / "poses").mkdir()
    shutil.copy(src / "poses" / "00.txt", tmp_path / "kitti" / "dataset" / "poses" / "00.txt")
    return tmp_path / "kitti", seq


def edit_line(path, number, fn):
    lines = path.read_text().splitlines()
    lines[number - 1] = fn(lines[number - 1])
    path.write_text("\n".join(lines) + "\n")


def as_folder(path):
    path.unlink()
    path.mkdir()


def nan_first_number(line):
    key, _, rest = line.partition(":") if ":" in line else ("", "", line)
    numbers = rest.split()
    return (f"{key}: " if key else "") + " ".join(["nan", *numbers[1:]])


# (what to break, --pair, fragments of the one-line error)
KITTI_CASES = {
    "nan-in-calib": (lambda seq, root: edit_line(seq / "calib.txt", 1, nan_first_number), "temporal",
                     ("calib.txt", "'P0' holds NaN")),
    "no-P1-in-calib": (lambda seq, root: edit_line(seq / "calib.txt", 2, lambda line: "# " + line), "stereo",
                       ("--cams: camera 1 has no 'P1' entry in", "calib.txt", "(it has P0, P2, P3)")),
    "nan-in-poses": (lambda seq, root: edit_line(root / "dataset/poses/00.txt", 2, nan_first_number), "temporal",
                     ("poses", "00.txt:2: NaN")),
    "calib-is-a-folder": (lambda seq, root: as_folder(seq / "calib.txt"), "temporal",
                          ("calib.txt: a folder, not a file",)),
    "poses-is-a-folder": (lambda seq, root: as_folder(root / "dataset/poses/00.txt"), "temporal",
                          ("00.txt: a folder, not a file",)),
    "image-is-a-folder": (lambda seq, root: (seq / "image_0/000001.png").unlink() or (seq / "image_0/000001.png").mkdir(),
                          "temporal", ("image", "000001.png: a folder, not a file")),
}


@pytest.mark.parametrize("case", sorted(KITTI_CASES))
def test_broken_kitti_files_are_one_line_errors(kitti_root, tmp_path, case):
    root, seq = small_layout(tmp_path, kitti_root)
    breaks, kind, fragments = KITTI_CASES[case]
    breaks(seq, root)
    out = tmp_path / "x.rrd"
    r = run_fviz("inspect", "pair", "--kitti-root", root, "--sequence", "00", "--pair", kind, "--out", out)
    assert_one_line_error(r, 2, *fragments)
    assert not out.exists()
    r = run_fviz("eval", "--kitti-root", root, "--sequence", "00", "--pair", kind, *SMALL, "--out-dir", tmp_path / "run")
    if case == "image-is-a-folder":  # a bad image fails its pair only, and the run goes on
        assert r.returncode == 0, r.stderr
        errors = {row["name"]: row["pair_error"] for row in read_csv(tmp_path / "run" / "metrics.csv")}
        assert [e for e in errors.values() if e] == ["image " + str(seq / "image_0/000001.png") + ": a folder, not a file"] * 2
    else:
        assert_one_line_error(r, 2, *fragments)
        assert not (tmp_path / "run").exists()


@pytest.mark.skipif(ROOT, reason="root reads files whatever their mode: the folder-in-place-of-a-file cases cover unreadable files")
@pytest.mark.parametrize("which", ["calib", "poses"])
def test_unreadable_calibration_or_poses(kitti_root, tmp_path, which):
    root, seq = small_layout(tmp_path, kitti_root)
    path = seq / "calib.txt" if which == "calib" else root / "dataset/poses/00.txt"
    path.chmod(0)
    r = run_fviz("inspect", "pair", "--kitti-root", root, "--sequence", "00", "--pair", "temporal", "--out", tmp_path / "x.rrd")
    assert_one_line_error(r, 2, f"cannot read {'calibration' if which == 'calib' else 'poses'} {path}", "Permission denied")


def unwritable_folder(tmp_path):
    """A folder no file can be created in: mode 0555, or, for root (who ignores modes), /sys/kernel."""
    if not ROOT:
        d = tmp_path / "readonly"
        d.mkdir()
        d.chmod(stat.S_IRUSR | stat.S_IXUSR)
        return d
    d = next((p for p in ("/sys/kernel", "/proc/self") if os.path.isdir(p)), None)
    try:
        open(os.path.join(d, "fviz-probe"), "w").close()
    except OSError:
        return __import__("pathlib").Path(d)
    os.remove(os.path.join(d, "fviz-probe"))
    pytest.skip("no unwritable folder on this machine")


@pytest.mark.parametrize("command", ["eval", "triage"])
def test_read_only_out_dir(kitti_root, tmp_path, command):
    d = unwritable_folder(tmp_path)
    for out in (d, d / "run"):
        r = run_fviz(command, "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", "0:3",
                     *SMALL, "--out-dir", out)
        assert_one_line_error(r, 2, f"--out-dir {out}: cannot write there")
    assert not (d / "run").exists()


def odometry(kitti_root, frames="0:8"):
    return ("--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", frames)


@pytest.mark.parametrize("command, args, fragment", [
    ("eval", ("--eval-threshold", "nan"), "--eval-threshold nan: must be a number > 0"),
    ("eval", ("--eval-threshold", "-1"), "--eval-threshold -1.0: must be a number > 0"),
    ("eval", ("--threshold", "nan"), "--threshold nan: must be a number > 0"),
    ("eval", ("--workers", "0"), "--workers 0: must be >= 1"),
    ("eval", ("--workers", "-5"), "--workers -5: must be >= 1"),
    ("eval", ("--ratio", "1.5"), "--ratio 1.5: must be a number in (0, 1]"),
    ("triage", ("--confidence", "inf"), "--confidence inf: must be a number in (0, 1]"),
    ("inspect", ("--eval-threshold", "nan"), "--eval-threshold nan"),
    ("inspect", ("--threshold", "-2"), "--threshold -2.0"),
    ("inspect", ("--out", "{tmp}/x.txt"), "--out {tmp}/x.txt: a recording must end in .rrd (e.g. {tmp}/x.rrd)"),
])
def test_nonsense_numbers_and_names_are_refused(kitti_root, tmp_path, command, args, fragment):
    args = tuple(a.replace("{tmp}", str(tmp_path)) for a in args)
    where = ("--out", tmp_path / "x.rrd") if command == "inspect" and "--out" not in args else ("--out-dir", tmp_path / "run")
    if command == "inspect":
        r = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", *args, *where[:2] if "--out" not in args else ())
    else:
        r = run_fviz(command, *odometry(kitti_root), *SMALL, *args, *where)
    assert_one_line_error(r, 2, fragment.replace("{tmp}", str(tmp_path)))
    assert not any(tmp_path.iterdir())


def test_too_many_workers_are_capped_at_the_cores(kitti_root, tmp_path):
    cores = len(os.sched_getaffinity(0))
    r = run_fviz("eval", *odometry(kitti_root, "0:9"), "-e", "8point", *SMALL, "--workers", "1000", "--out-dir", tmp_path / "run")
    assert r.returncode == 0, r.stderr
    assert f"note: --workers 1000 capped at {cores}, the CPU cores here" in r.stderr
    records = [json.loads(line) for line in open(tmp_path / "run" / "results.jsonl")]
    assert len(records) == 8 and len({rec["worker"] for rec in records}) <= cores


def test_shard_help_says_shards_count_from_0():
    r = run_fviz("eval", "--help")
    text = " ".join(re.sub(r"[│╭╮╰╯─]", " ", r.stdout).split())
    assert "run only block i of n contiguous blocks of pairs, counting from 0 (0/4 .. 3/4" in text


def test_resume_of_a_folder_that_does_not_exist(tmp_path):
    for command, verb in (("eval", "resume"), ("triage", "use")):
        extra = ("--resume",) if command == "eval" else ()
        r = run_fviz(command, "--out-dir", tmp_path / "nothing", *extra)
        assert_one_line_error(r, 2, f"--out-dir {tmp_path / 'nothing'}: no run to {verb} (no such folder)")
        assert "--kitti-root: missing" not in r.stderr
    assert not (tmp_path / "nothing").exists()


@pytest.fixture(scope="module")
def small_run(kitti_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("bad_input") / "run"
    r = run_fviz("eval", *odometry(kitti_root), "-e", "8point", "-e", "magsac", "-e", "oracle-mean", *SMALL,
                 "--workers", "1", "--out-dir", out)
    assert r.returncode == 0, r.stderr
    return out


def test_resume_with_other_flags_names_them_with_both_values(small_run, kitti_root):
    before = (small_run / "results.jsonl").read_bytes()
    r = run_fviz("eval", *odometry(kitti_root, "0:9"), "-e", "8point", "-e", "magsac", "-e", "oracle-mean", *SMALL,
                 "--threshold", "2", "--resume", "--out-dir", small_run)
    assert_one_line_error(r, 2, f"--resume: {small_run} was run with other options (--threshold 1.0 in the run, 2.0 now; "
                                "--frames 0:8 in the run, 0:9 now); use the same flags or another --out-dir")
    assert (small_run / "results.jsonl").read_bytes() == before


def without_timings(rows):
    return [{k: v for k, v in row.items() if k != "seconds"} for row in rows]


@pytest.mark.parametrize("command", ["eval", "triage"])
def test_malformed_results_lines_are_skipped_with_a_warning_and_recomputed(small_run, tmp_path, command):
    run = tmp_path / "run"
    shutil.copytree(small_run, run)
    expected = without_timings(read_csv(small_run / "metrics.csv"))
    path = run / "results.jsonl"
    lines = path.read_text().splitlines()
    lines[2] = "null"
    rec = json.loads(lines[4])
    rec["kee"] = rec.pop("key")
    lines[4] = json.dumps(rec)
    rec = json.loads(lines[5])
    rec["result"]["estimators"][1]["metrics"] = None
    lines[5] = json.dumps(rec)
    path.write_text("\n".join(lines) + "\n")
    r = run_fviz(command, "--out-dir", run, *(("--resume",) if command == "eval" else ()), "--no-progress", "--workers", "1")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    warnings = [line for line in r.stderr.splitlines() if line.startswith("warning:")]
    assert warnings == [
        f"warning: {path}:3: not a pair record (null); skipped, its pair is evaluated again",
        f"warning: {path}:5: not a pair record (no 'key'); skipped, its pair is evaluated again",
        f"warning: {path}:6: not a pair record ('result.estimators[].metrics' is NoneType); skipped, its pair is evaluated again",
    ]
    assert "7 pairs (4 already done, 3 evaluated now, 0 not evaluated (pair errors)" in r.stderr
    assert without_timings(read_csv(run / "metrics.csv")) == expected
    if command == "triage":
        assert (run / "triage.md").is_file()


def test_user_estimator_returning_junk_fails_only_itself(kitti_root, tmp_path):
    (tmp_path / "junk_est.py").write_text(
        "import numpy as np\n"
        "def text(pair, x_a, x_b):\n    return 'not a matrix'\n"
        "def small(pair, x_a, x_b):\n    return [[1, 2], [3, 4]]\n"
        "def triple(pair, x_a, x_b):\n    return np.eye(3), None, 1\n"
    )
    r = run_fviz("eval", *odometry(kitti_root, "0:3"), "-e", "ransac", "-e", "junk_est:text", "-e", "junk_est:small",
                 "-e", "junk_est:triple", *SMALL, "--workers", "1", "--out-dir", tmp_path / "run", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "0 not evaluated (pair errors)" in r.stderr
    rows = read_csv(tmp_path / "run" / "metrics.csv")
    assert len(rows) == 2 * 5 and not any(row["pair_error"] for row in rows)
    for row in rows:
        if row["estimator"] in ("gt", "ransac"):
            assert not row["error"] and math.isfinite(float(row["sed_median"]))
        else:
            assert row["error"].startswith("returned ") and "not F or (F, inlier_mask)" in row["error"]
    errors = {row["estimator"]: row["error"] for row in rows if row["index"] == "0"}
    assert errors["text"].startswith("returned str 'not a matrix'")
    assert errors["small"].endswith("(shape (2, 2))")
    assert errors["triple"].endswith("(a tuple of 3 items)")


def test_two_checkpoints_of_one_file_name_keep_their_own_names(tmp_path):
    for run in ("a", "b"):
        (tmp_path / "runs" / run).mkdir(parents=True)
        (tmp_path / "runs" / run / "model.pt").symlink_to(BUNDLED)
    out = tmp_path / "two.rrd"
    r = run_fviz("inspect", "pair", "--synthetic", "--seed", "3", "--pair", "temporal", "-e", "deep:runs/a/model.pt",
                 "-e", "deep:runs/b/model.pt", "-e", "8point", "--out", out, "--json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert [e["name"] for e in doc["estimators"]] == ["gt", "deep-a-model", "deep-b-model", "8point"]
    from fviz.record import layout as L
    from fviz.record.summary import read_recording

    s = read_recording(out)
    assert {"deep-a-model", "deep-b-model"} <= set(s.estimators)
    assert {L.est("a", "deep-a-model", "epilines"), L.est("a", "deep-b-model", "epilines")} <= set(s.entity_paths)


def test_summary_of_a_foreign_recording_invents_no_names(tmp_path):
    import rerun as rr

    path = tmp_path / "foreign.rrd"
    rec = rr.RecordingStream("someone-elses-app")
    rec.save(str(path))
    for step in range(3):
        rec.set_time("step", sequence=step)
        rec.log("metrics/loss", rr.Scalars([0.5 / (step + 1)]))
        rec.log("metrics/acc", rr.Scalars([0.1 * step, 0.2 * step]))
    rec.flush()
    del rec
    r = run_fviz("summary", path, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    # fviz reads its own per-pair table (pair/metrics): another program's series are listed as entities,
    # never given made-up estimator names
    assert doc["app_id"] == "someone-elses-app" and doc["items"] == [] and doc["estimators"] == []
    assert {"metrics/acc", "metrics/loss"} <= set(doc["entity_paths"])
    assert "series" not in r.stdout
    table = run_fviz("summary", path)
    assert table.returncode == 0 and "no pairs in" in table.stdout and "metrics/loss" in table.stdout
