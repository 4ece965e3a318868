"""Benchmark ``fviz eval`` (a script, not a test).

1. Speed: the 49 temporal pairs (step 1) of KITTI sample sequence 00 with SIFT (2000) + MAGSAC++, three
   figures measured in the same round, rounds alternating (``--repeat``):
   - the plain OpenCV loop: every pair decodes and detects both its images again (SIFT, BFMatcher knn +
     ratio test, cv2.findFundamentalMat USAC_MAGSAC), one process;
   - the limit of the machine: single-thread SIFT (``cv2.setNumThreads(1)``, ``detectAndCompute`` only, the
     50 frames decoded beforehand), summed CPU time divided by the cores (= the workers): every frame detected
     once, every core busy, nothing else done;
   - ``fviz eval ... -e magsac`` (a subprocess: start-up and reports included) on the same pairs.
   Target: eval <= 1.25x the limit (it also prints eval / plain loop). Beside them: eval's start-up (launch to
   the start of its first pair, less the interpreter's own start) and, once, the CPU per pair outside SIFT
   (``PairEvaluator`` over the run's frame schedule in one single-threaded process: every task's CPU less
   its feature detection). fviz runs with cached bytecode (``PYTHONDONTWRITEBYTECODE`` unset), as installed.
   Last, the floor: the CPU a pair of what no correct eval skips besides SIFT (decoding, exact matching,
   MAGSAC++; single thread, each at its fastest here), and the eval / limit it alone would give.
2. Memory: peak RSS (max over the run's processes, ``getrusage(RUSAGE_CHILDREN)`` of a fresh
   subprocess per size) of ``fviz eval`` on a small and a 10x larger selection of synthetic pairs. Target:
   flat, ratio <= 1.05.

    python benchmarks/bench_eval.py [--kitti-root DIR] [--workers N] [--repeat 3] [--small 100 --large 1000] [--skip-memory]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PROJECT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(PROJECT))  # this checkout's fviz, wherever the script is started from
DEFAULT_ROOT = Path(os.environ.get("FVIZ_KITTI_ROOT", PROJECT.parent / "shared" / "data" / "kitti"))
FRAMES = 50
SELECTION = ["--sequence", "00", "--pair", "temporal", "--step", "1", "--frames", f"0:{FRAMES}", "-e", "magsac"]
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}  # fviz as installed: bytecode cached


def frame_paths(root: Path, frames: int = FRAMES) -> list[Path]:
    """The sample frames of sequence 00, camera 0; exits naming what is missing (cv2.imread would return None)."""
    images = root / "odometry" / "dataset" / "sequences" / "00" / "image_0"
    paths = [images / f"{f:06d}.png" for f in range(frames)]
    missing = [p for p in paths if not p.is_file()]
    if missing:
        raise SystemExit(f"bench_eval: {len(missing)} of the {frames} frames missing, e.g. {missing[0]} "
                         f"(give --kitti-root or $FVIZ_KITTI_ROOT: the KITTI samples, ../shared/data/kitti)")
    return paths


def read_gray(path: Path):
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise SystemExit(f"bench_eval: cannot decode {path}")
    return img


def cpu_seconds(who) -> float:
    import resource

    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def plain_magsac(x_a, x_b):
    """MAGSAC++ as the plain loop calls it: OpenCV's flag, 1 px, confidence 0.999, 10,000 iterations."""
    import cv2

    return cv2.findFundamentalMat(x_a, x_b, cv2.USAC_MAGSAC, 1.0, 0.999, 10000)


def plain_opencv(root: Path, max_keypoints: int = 2000, ratio: float = 0.8) -> tuple[float, float]:
    """(wall seconds, CPU seconds) of the naive loop: every pair decodes and detects both its images again."""
    import resource

    import cv2
    import numpy as np

    paths = frame_paths(root)
    sift, bf = cv2.SIFT_create(nfeatures=max_keypoints), cv2.BFMatcher(cv2.NORM_L2)
    t0, c0 = time.perf_counter(), cpu_seconds(resource.RUSAGE_SELF)
    for f in range(len(paths) - 1):
        a, b = read_gray(paths[f]), read_gray(paths[f + 1])
        ka, da = sift.detectAndCompute(a, None)
        kb, db = sift.detectAndCompute(b, None)
        good = [m for m, n in bf.knnMatch(da, db, k=2) if m.distance < ratio * n.distance]
        xa = np.float64([ka[m.queryIdx].pt for m in good])
        xb = np.float64([kb[m.trainIdx].pt for m in good])
        plain_magsac(xa, xb)
    return time.perf_counter() - t0, cpu_seconds(resource.RUSAGE_SELF) - c0


def sift_cpu(root: Path, max_keypoints: int = 2000) -> float:
    """Summed single-thread SIFT CPU time (s) of the frames, decoded beforehand: what no schedule can avoid."""
    import cv2

    images = [read_gray(p) for p in frame_paths(root)]
    sift = cv2.SIFT_create(nfeatures=max_keypoints)
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    total = 0.0
    try:
        for img in images:
            t0 = time.thread_time()  # CPU time: robust to other load on the machine
            sift.detectAndCompute(img, None)
            total += time.thread_time() - t0
    finally:
        cv2.setNumThreads(threads)
    return total


def floor_per_pair(root: Path, max_keypoints: int = 2000) -> dict[str, float]:
    """Single-thread CPU ms a pair of what any eval of these pairs must do besides SIFT, each at its fastest
    here: decode the frames (PNG, once each), match exactly (fviz's matcher, equal to OpenCV's brute force
    + ratio test; of it the distance GEMM alone) and run MAGSAC++ (as the plain loop calls it)."""
    import cv2
    import numpy as np

    from fviz.estimators.features import FeatureConfig, detect, match

    paths = frame_paths(root)
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        t0 = time.thread_time()
        images = [read_gray(p) for p in paths]
        decode = time.thread_time() - t0
        cfg = FeatureConfig(max_keypoints=max_keypoints)
        feats = [detect(img, cfg) for img in images]
        matching = gemm = magsac = 0.0
        for fa, fb in zip(feats, feats[1:]):
            t0 = time.thread_time()
            m = match(fa, fb, cfg)
            t1 = time.thread_time()
            np.dot(fa.descriptors, fb.descriptors.T)
            t2 = time.thread_time()
            plain_magsac(m.x_a, m.x_b)
            t3 = time.thread_time()
            matching, gemm, magsac = matching + t1 - t0, gemm + t2 - t1, magsac + t3 - t2
    finally:
        cv2.setNumThreads(threads)
    pairs = len(paths) - 1
    ms = {"decode": decode, "matching": matching, "gemm": gemm, "magsac": magsac}
    return {k: 1e3 * v / pairs for k, v in ms.items()}


def interpreter_seconds(repeat: int = 3) -> float:
    """Median wall time of ``python -c pass``: the start-up every command pays before its own."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], check=True, env=ENV)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def fviz_eval(args: list[str], out_dir: Path | None = None) -> tuple[float, float, dict]:
    """(wall seconds, peak RSS in MiB over the run's processes, {"cpu": CPU seconds of all of them,
    "summary": fviz's last line, "startup": seconds from launch to the start of the first pair (with
    ``out_dir``, from its results.jsonl)}) of one ``fviz eval`` in a fresh subprocess."""
    code = (
        "import resource, subprocess, sys, time, json\n"
        "t0, launched = time.perf_counter(), time.time()\n"
        "p = subprocess.run([sys.executable, '-m', 'fviz', 'eval', *sys.argv[1:]], capture_output=True, text=True)\n"
        "dt = time.perf_counter() - t0\n"
        "r = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
        "print(json.dumps({'rc': p.returncode, 'seconds': dt, 'rss_mib': r.ru_maxrss / 1024, 'launched': launched,\n"
        "                  'cpu': r.ru_utime + r.ru_stime, 'err': p.stderr[-2000:]}))\n"
    )
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, check=True, cwd=PROJECT, env=ENV)
    res = json.loads(out.stdout)
    if res["rc"] != 0:
        raise SystemExit(f"fviz eval failed ({res['rc']}): {res['err']}")
    line = next((ln for ln in res["err"].splitlines() if ln.startswith("eval:")), "")
    info = {"summary": line.strip(), "cpu": res["cpu"], "startup": float("nan")}
    if out_dir is not None:
        recs = [json.loads(ln) for ln in (out_dir / "results.jsonl").read_text().splitlines() if ln.strip()]
        info["startup"] = min(r["finished_at"] - r["seconds"] for r in recs) - res["launched"]
    return res["seconds"], res["rss_mib"], info


PER_PAIR = """
import importlib, json, sys, time
from pathlib import Path
from fviz.run.prestart import WORKER_PRELOAD
for name in WORKER_PRELOAD:  # what a worker imports before its first pair (start-up, not per pair)
    importlib.import_module(name)
import cv2
import fviz.estimators.features as features
from fviz.cli.eval import RUN_PARAMS, RunArgs
from fviz.run.config import prepare
from fviz.run.evaluator import CACHE_FRESH, CACHE_NOTES, PairEvaluator
from fviz.run.schedule import FrameSchedule, schedule_window

cv2.setNumThreads(1)
detect, sift = features.detect, [0.0]
def timed(*a, **k):
    t0 = time.process_time()
    try:
        return detect(*a, **k)
    finally:
        sift[0] += time.process_time() - t0
features.detect = timed
values = {p.name: p.default for p in RUN_PARAMS}
values.update(kitti_root=Path(sys.argv[1]), sequence="00", pair_kind=["temporal"], step=["1"], frames="0:%d", estimator=["magsac"])
config = prepare(RunArgs(values).config(()))
todo = config.pairs()
schedule = FrameSchedule(todo, schedule_window(todo, 2))
evaluator = PairEvaluator(config, Path(sys.argv[2]), detect_threads=1)
total = 0.0
while (task := schedule.next_task()) is not None:
    t0 = time.process_time()
    rec, kept = evaluator.run_task(task)
    rec.pop(CACHE_FRESH, None), rec.pop(CACHE_NOTES, None)  # the run folder's features.h5 entries, written apart
    json.dumps(rec)  # results.jsonl
    total += time.process_time() - t0
    schedule.done(task, kept)
print(json.dumps({"pairs": len(todo), "cpu": total, "sift": sift[0], "detections": evaluator.cache.misses}))
""" % FRAMES


def per_pair_outside_sift(root: Path) -> dict:
    """CPU seconds per pair outside feature detection, over the run's frame schedule in one single-threaded
    process (as one worker would, every pair, its imports done first as a worker's are)."""
    env = {**ENV, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run([sys.executable, "-c", PER_PAIR, str(root), tmp], capture_output=True, text=True,
                             cwd=PROJECT, env=env)
    if out.returncode != 0:
        raise SystemExit(f"per-pair measurement failed: {out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def speed(root: Path, workers: int, repeat: int) -> None:
    """``repeat`` alternating rounds of: plain loop, fviz eval, single-thread SIFT of every frame."""
    med = statistics.median
    frame_paths(root)
    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:  # warm-up: the bytecode of this checkout written once
        fviz_eval(["--kitti-root", str(root), "--sequence", "00", "--pair", "temporal", "--frames", "0:9", "-e", "magsac",
                   "--workers", str(workers), "--no-progress", "--out-dir", f"{tmp}/run"])
    load0 = os.getloadavg()[0]
    rows: list[dict] = []
    for _ in range(repeat):
        wall, cpu = plain_opencv(root)
        with tempfile.TemporaryDirectory() as tmp:
            fw, _, info = fviz_eval(["--kitti-root", str(root), *SELECTION, "--workers", str(workers),
                                     "--no-progress", "--out-dir", f"{tmp}/run"], Path(tmp) / "run")
        rows.append({"plain": wall, "plain_cpu": cpu, "fviz": fw, "fviz_cpu": info["cpu"],
                     "limit": sift_cpu(root) / workers, "startup": info["startup"] - interpreter_seconds(),
                     "summary": info["summary"]})
    m = {k: med(r[k] for r in rows) for k in rows[0] if k != "summary"}
    to_limit = [r["fviz"] / r["limit"] for r in rows]
    to_plain = [r["fviz"] / r["plain"] for r in rows]
    print(f"speed, {FRAMES - 1} temporal pairs of sequence 00, SIFT (2000) + MAGSAC++, {cores} cores, {workers} workers, "
          f"{repeat} alternating rounds (medians; load average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end):")
    print(f"  plain OpenCV loop:        {m['plain']:7.2f} s wall, {m['plain_cpu']:6.2f} s CPU   (decode + features per pair, one process)")
    print(f"  limit:                    {m['limit']:7.2f} s   (single-thread SIFT of the {FRAMES} decoded frames / {workers} workers)"
          f" = {m['limit'] / m['plain']:.2f} x plain")
    print(f"  fviz eval --workers {workers}:    {m['fviz']:7.2f} s wall, {m['fviz_cpu']:6.2f} s CPU   ({rows[-1]['summary']})")
    print(f"  eval / limit:             {med(to_limit):7.2f}   per round: {', '.join(f'{r:.2f}' for r in to_limit)}   (target <= 1.25)")
    print(f"  eval / plain loop:        {med(to_plain):7.2f}   per round: {', '.join(f'{r:.2f}' for r in to_plain)}")
    to_sift = [r["fviz_cpu"] / (r["limit"] * workers) for r in rows]
    print(f"  eval CPU / SIFT CPU:      {med(to_sift):7.2f}   per round: {', '.join(f'{r:.2f}' for r in to_sift)}   "
          "(all of eval's processes against the limit's SIFT; the wall ratios need a quiet machine, this one less so)")
    print(f"  eval start-up:            {m['startup']:7.2f} s   (launch to its first pair, less the interpreter's own start; target <= 0.3)")
    pp = per_pair_outside_sift(root)
    print(f"  per pair outside SIFT:    {1e3 * (pp['cpu'] - pp['sift']) / pp['pairs']:7.1f} ms CPU   (one process over the schedule: "
          f"{pp['cpu']:.2f} s CPU, of it {pp['sift']:.2f} s detection, {pp['detections']} detections; target <= 20)")
    fl = floor_per_pair(root)
    floor_ms = fl["decode"] + fl["matching"] + fl["magsac"]
    print(f"  floor per pair:           {floor_ms:7.1f} ms CPU   (decode {fl['decode']:.1f} + exact matching {fl['matching']:.1f}, "
          f"its GEMM alone {fl['gemm']:.1f}, + MAGSAC++ {fl['magsac']:.1f}: what no correct eval skips, besides SIFT)")
    floor_ratio = (m["limit"] * workers + 1e-3 * floor_ms * (FRAMES - 1)) / workers / m["limit"]
    print(f"  floor / limit:            {floor_ratio:7.2f}   (SIFT and the floor on {workers} busy cores, with no start-up, "
          "metrics, triage evidence or reports)")


def memory(root: Path, workers: int, small: int, large: int) -> None:
    try:
        import fviz.data.synthetic  # noqa: F401

        sel = lambda n: ["--synthetic", "--seeds", f"0:{n}", "--pair", "temporal"]  # noqa: E731
        what = "synthetic temporal pairs"
    except ImportError:
        small, large = 10, 49
        sel = lambda n: ["--kitti-root", str(root), "--sequence", "00", "--pair", "temporal", "--frames", f"0:{n + 1}"]  # noqa: E731
        what = "KITTI temporal pairs (no synthetic source)"
    rss = {}
    for n in (small, large):
        with tempfile.TemporaryDirectory() as tmp:
            sec, rss[n], info = fviz_eval([*sel(n), "-e", "8point", "--features", "orb", "--max-keypoints", "500",
                                           "--workers", str(workers),
                                           "--no-progress", "--out-dir", f"{tmp}/run"])
        print(f"  {n:5d} {what}: peak RSS {rss[n]:7.1f} MiB, {sec:7.1f} s")
    print(f"  ratio {large}/{small}: {rss[large] / rss[small]:.3f} (target: flat, <= 1.05)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kitti-root", type=Path, default=DEFAULT_ROOT)
    ap.add_argument("--workers", type=int, default=os.cpu_count())
    ap.add_argument("--small", type=int, default=100)
    ap.add_argument("--large", type=int, default=1000)
    ap.add_argument("--skip-memory", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--repeat", type=int, default=3, help="alternating rounds of the speed comparison")
    a = ap.parse_args()
    if not a.skip_speed:
        speed(a.kitti_root, a.workers, a.repeat)
    if not a.skip_memory:
        print("memory:")
        memory(a.kitti_root, a.workers, a.small, a.large)


if __name__ == "__main__":
    main()
