"""Run estimators over every pair of a selection (what ``fviz eval`` and ``fviz triage`` do).

A run lives in one ``--out-dir``::

    run.json         the run's configuration (selection, estimator options, constant-F baseline)
    results.jsonl    one JSON record per finished pair, appended and flushed as pairs finish: the
                     source of truth (``--resume`` skips the pairs it holds; a later record of a pair
                     supersedes an earlier one; a line cut by a crash is ignored)
    metrics.csv      PairResult.rows() of every pair: one row per pair x estimator, ``gt`` included
    metrics.parquet  the same rows
    summary.md       per-estimator statistics and the paper-style table
    eval.rrd         every pair on the ``pair`` timeline: pair/info, summary, errors, metric series
    pairs/NNNNNN.npz with ``--full`` only: matches, inlier masks and residuals, so that eval.rrd can
                     carry each pair's full inspect payload (images re-read from the source)

The four reports are regenerated from results.jsonl at the end of every run, an interrupted one
included, so they are always complete up to the last finished pair.

Speed: pairs are sorted frame-major and split into contiguous chunks, one per worker process; each
worker keeps a :class:`FeatureCache`, so a frame shared by neighbouring pairs is detected once
(measured by the ``detections`` field of each record). Memory: a worker loads one pair at a time;
the main process keeps only file offsets of results.jsonl and per-metric floats for the summary.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import time
from array import array
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from fviz.atomic import tmp_path, write_text
from fviz.estimators.options import EstimatorOptions
from fviz.data.kitti import PAIR_KINDS
from fviz.data.pair import PairId
from fviz.errors import FvizError
from fviz.evaluate import EVAL_THRESHOLD_PX, GT_NAME, MIN_MATCHES, EstimatorResult, PairResult

RUN_FILE = "run.json"
RESULTS_FILE = "results.jsonl"
CSV_FILE = "metrics.csv"
PARQUET_FILE = "metrics.parquet"
SUMMARY_FILE = "summary.md"
RRD_FILE = "eval.rrd"
PAYLOAD_DIR = "pairs"

CONSTANT = "constant"  # the constant-F baseline: the mean ground-truth F of the selection
MIN_PAIRS_PER_WORKER = 4  # fewer pairs than this per process: starting one costs more than it saves
CACHE_ITEMS = 16  # features kept per worker, plus 2 per frame of the largest step (frame-major order)

# Columns of the CSV that are text or integers; every other column is a float.
TEXT_COLUMNS = ("name", "source", "root", "sequence", "kind", "estimator", "norm", "error", "pair_error")
INT_COLUMNS = ("index", "frame_a", "frame_b", "cam_a", "cam_b", "n_matches", "n_eval")
# Metrics summarised per estimator in summary.md (mean, median, p90, p99).
SUMMARY_METRICS = ("sed_median", "sampson_median", "epi_abs", "epi_sqr", "inlier_ratio", "f_dist", "epipole_err_deg", "seconds")
PERCENTILES = (90, 99)
PAPER_NORMS = ("fbn", "abs", "etr")
PAPER_COLUMNS = tuple(f"epi_{m}_{n}" for n in PAPER_NORMS for m in ("abs", "sqr"))


# ------------------------------------------------------------------------------------ selection


@dataclass(frozen=True)
class Selection:
    """Which pairs: a KITTI sequence/drive (kinds x steps over a frame range) or synthetic seeds.

    frames: (start, end) of camera-0 frames, end exclusive, None = the sequence's ends; both frames
    of a pair lie in the range. seeds: (first, last + 1) of synthetic scenes, one pair per seed and kind.
    """

    kitti_root: str | None = None
    sequence: str | None = None
    drive: str | None = None
    kinds: tuple[str, ...] = ("stereo",)
    steps: tuple[int, ...] = (1,)
    cams: tuple[int, int] | None = None
    frames: tuple[int | None, int | None] = (None, None)
    synthetic: bool = False
    seeds: tuple[int, int] | None = None

    def __post_init__(self):
        for kind in self.kinds:
            if kind not in PAIR_KINDS:
                raise FvizError(f"--pair {kind!r}: choose one of {', '.join(PAIR_KINDS)}")
        if not self.kinds:
            raise FvizError("--pair: give at least one of stereo, temporal")
        if any(s < 1 for s in self.steps):
            raise FvizError(f"--step {min(self.steps)}: must be >= 1")
        if self.synthetic and self.seeds is None:
            raise FvizError("--synthetic: give the scenes as --seeds A:B (seeds A .. B-1)")
        if not self.synthetic and self.seeds is not None:
            raise FvizError("--seeds: only with --synthetic")
        if self.synthetic:
            kitti_only = {"--kitti-root": self.kitti_root, "--sequence": self.sequence, "--drive": self.drive,
                          "--cams": self.cams, "--frames": self.frames != (None, None) or None,
                          "--step": self.steps != (1,) or None}
            given = [flag for flag, v in kitti_only.items() if v is not None]
            if given:
                raise FvizError(f"{given[0]}: KITTI selections only, not with --synthetic (select scenes with --seeds A:B)")
        if self.seeds is not None and not 0 <= self.seeds[0] < self.seeds[1]:
            raise FvizError(f"--seeds {self.seeds[0]}:{self.seeds[1]}: need 0 <= A < B")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Selection":
        tup = lambda v: None if v is None else tuple(v)  # noqa: E731
        return cls(**{**d, **{k: tup(d.get(k)) for k in ("kinds", "steps", "cams", "frames", "seeds")}})

    def source(self) -> "KittiSource | SyntheticSource":
        return SyntheticSource(self) if self.synthetic else KittiSource(self)

    def describe(self) -> str:
        if self.synthetic:
            return f"synthetic seeds {self.seeds[0]}..{self.seeds[1] - 1} ({'/'.join(self.kinds)})"
        what = f"sequence {self.sequence}" if self.sequence else f"drive {self.drive}" if self.drive else "auto-detected"
        frames = "all frames" if self.frames == (None, None) else f"frames {_range_text(self.frames)}"
        steps = f", step {'/'.join(map(str, self.steps))}" if "temporal" in self.kinds else ""
        return f"KITTI {what} under {self.kitti_root}: {'/'.join(self.kinds)} pairs{steps}, {frames}"


def _range_text(r: tuple[int | None, int | None]) -> str:
    return f"{'' if r[0] is None else r[0]}:{'' if r[1] is None else r[1]}"


class KittiSource:
    """Pairs of one KITTI odometry sequence or raw drive."""

    def __init__(self, sel: Selection):
        from fviz.data.kitti import open_dataset

        if sel.kitti_root is None:
            raise FvizError("--kitti-root: missing (or set $FVIZ_KITTI_ROOT); use --synthetic --seeds A:B for scenes that need no dataset")
        self.sel = sel
        self.ds = open_dataset(sel.kitti_root, sel.sequence, sel.drive)

    def _frame_range(self) -> range:
        n = self.ds.num_frames
        start, end = self.sel.frames
        start, end = 0 if start is None else start, n if end is None else end
        if not 0 <= start < end <= n:
            raise FvizError(f"--frames {_range_text(self.sel.frames)}: {self.ds.source} {self.ds.name} has frames 0..{n - 1} "
                            "(START:END, END exclusive)")
        return range(start, end)

    def pair_ids(self) -> list[PairId]:
        """Frame-major (frame, kind, step) order, so that pairs sharing a frame are neighbours."""
        frames = self._frame_range()
        if "temporal" in self.sel.kinds:
            _ = self.ds.poses  # a one-line error now when the layout has no poses
        ids = []
        for frame in frames:
            for kind in self.sel.kinds:
                for step in self.sel.steps if kind == "temporal" else (0,):
                    if frame + step < frames.stop:
                        ids.append(self.ds.pair_id(frame, kind, max(step, 1), self.sel.cams))
        if not ids:
            raise FvizError(f"--frames {_range_text(self.sel.frames)}: no pair fits in the range (step {max(self.sel.steps)})")
        return ids

    def load(self, pid: PairId):
        return self.ds.load(pid)

    def ground_truth(self, pid: PairId) -> np.ndarray:
        return self.ds.ground_truth(pid)[4]

    def inspect_args(self, pid: PairId) -> list[str]:
        """The ``fviz inspect pair`` flags that select this pair."""
        where = ["--sequence", self.ds.name] if self.ds.source == "odometry" else ["--drive", self.ds.name]
        args = ["--kitti-root", str(self.sel.kitti_root), *where, "--frame", str(pid.frame_a), "--pair", pid.kind]
        if pid.kind == "temporal":
            args += ["--step", str(pid.frame_b - pid.frame_a)]
        return args + ["--cams", f"{pid.cam_a},{pid.cam_b}"]


class SyntheticSource:
    """One synthetic pair per seed and kind (:mod:`fviz.data.synthetic`, imported lazily)."""

    def __init__(self, sel: Selection):
        try:
            from fviz.data import synthetic
        except ImportError as exc:
            raise FvizError(f"--synthetic: the synthetic data source is not available ({exc})") from None
        self.sel, self.mod = sel, synthetic

    def _config(self, kind: str):
        return self.mod.SceneConfig(stereo=kind == "stereo")

    def pair_ids(self) -> list[PairId]:
        a, b = self.sel.seeds
        return [PairId("synthetic", str(seed), kind, 0, 1, 0, 1 if kind == "stereo" else 0)
                for seed in range(a, b) for kind in self.sel.kinds]

    def load(self, pid: PairId):
        return self.mod.synthetic_pair(int(pid.sequence), self._config(pid.kind))

    def ground_truth(self, pid: PairId) -> np.ndarray:
        """F of the pair (the public API renders the pair: only the constant baseline needs this)."""
        return self.load(pid).F_gt

    def inspect_args(self, pid: PairId) -> list[str]:
        # inspect's --seed seeds both the scene and the robust estimators.
        return ["--synthetic", "--seed", pid.sequence, "--pair", pid.kind]


# ------------------------------------------------------------------------------ configuration


def parse_shard(text: str) -> tuple[int, int]:
    """``i/n`` (0 <= i < n) -> (i, n)."""
    try:
        i, n = (int(p) for p in text.split("/"))
    except ValueError:
        raise FvizError(f"--shard {text!r}: expected i/n, e.g. 0/4") from None
    if not 0 <= i < n:
        raise FvizError(f"--shard {text}: need 0 <= i < n")
    return i, n


def shard_slice(count: int, shard: tuple[int, int] | None) -> range:
    """Shard i of n: the i-th of n contiguous blocks (contiguous keeps shared frames in one job)."""
    if shard is None:
        return range(count)
    i, n = shard
    return range(i * count // n, (i + 1) * count // n)


@dataclass(frozen=True)
class RunConfig:
    """Everything that determines a run's results (what run.json holds)."""

    selection: Selection
    options: EstimatorOptions
    norm: str = "fbn"
    eval_threshold: float = EVAL_THRESHOLD_PX
    full: bool = False
    shard: tuple[int, int] | None = None
    constant_F: tuple[float, ...] | None = None  # 9 numbers, set by :func:`prepare`

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["selection"] = self.selection.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RunConfig":
        opts = dict(d["options"], names=tuple(d["options"]["names"]))
        return cls(
            selection=Selection.from_dict(d["selection"]), options=EstimatorOptions(**opts), norm=d["norm"],
            eval_threshold=d["eval_threshold"], full=d["full"], shard=None if d["shard"] is None else tuple(d["shard"]),
            constant_F=None if d["constant_F"] is None else tuple(d["constant_F"]),
        )

    def estimator_names(self) -> list[str]:
        """Display names, in order (``gt`` not included)."""
        from fviz.estimators.registry import display_name

        return [CONSTANT if n == CONSTANT else display_name(n) for n in self.options.names]

    def series_names(self) -> list[str]:
        """The order of PairResult.estimators: the ground truth, then the estimators."""
        return [GT_NAME, *self.estimator_names()]

    def pairs(self, source=None) -> list[tuple[int, PairId]]:
        """(index in the whole selection, pair) of this run's shard."""
        ids = (source or self.selection.source()).pair_ids()
        return [(i, ids[i]) for i in shard_slice(len(ids), self.shard)]

    def comparable(self) -> dict[str, Any]:
        """What must agree for two runs' records to be mixed (resume, merge): all but the estimator names
        (pairs lacking one are evaluated again), the shard and ``full`` (which only adds payload files)."""
        d = self.to_dict()
        d["options"] = {k: v for k, v in d["options"].items() if k != "names"}
        d.pop("shard")
        d.pop("full")
        return d

    def cache_items(self) -> int:
        """Features kept per worker: enough for the frames a frame-major window of pairs shares."""
        return CACHE_ITEMS + 2 * max(self.selection.steps)


def mean_fundamental(Fs: Iterable[np.ndarray]) -> np.ndarray:
    """The mean of F matrices up to scale and sign: each FBN-normalized and sign-aligned with the first,
    averaged, made rank 2 and normalized again."""
    from fviz.geometry import enforce_rank2, normalize

    acc, ref, n = np.zeros((3, 3)), None, 0
    for F in Fs:
        F = normalize(F, "fbn")
        ref = F if ref is None else ref
        acc += F if np.sum(F * ref) >= 0 else -F
        n += 1
    if n == 0:
        raise FvizError("no pair selected")
    return normalize(enforce_rank2(acc / n), "fbn")


def constant_estimator(F: np.ndarray) -> Callable:
    """The constant-F baseline: the same F for every pair, whatever the matches."""
    F = np.asarray(F, dtype=np.float64).reshape(3, 3)

    def constant(pair, x_a, x_b):
        return F

    return constant


def prepare(config: RunConfig) -> RunConfig:
    """Validate the estimators and the selection (one-line errors) and fix the constant-F baseline
    on the whole selection (not the shard: shards then merge to one run's results)."""
    from fviz.geometry import NORMS

    if config.norm not in NORMS:
        raise FvizError(f"--norm {config.norm!r}: choose one of {', '.join(NORMS)}")
    if config.eval_threshold <= 0:
        raise FvizError(f"--eval-threshold {config.eval_threshold}: must be > 0")
    names = config.options.names
    if len(set(names)) != len(names):
        raise FvizError(f"--estimator: repeated name in {', '.join(names)}")
    if not names:
        raise FvizError("--estimator: give at least one")
    replace(config.options, names=tuple(n for n in names if n != CONSTANT)).estimators()
    config.options.feature_config()
    source = config.selection.source()
    ids = source.pair_ids()
    if CONSTANT in names and config.constant_F is None:
        F = mean_fundamental(source.ground_truth(pid) for pid in ids)
        config = replace(config, constant_F=tuple(float(v) for v in F.ravel()))
    return config


def resolve_estimators(config: RunConfig) -> list[tuple[str, Callable]]:
    """[(display name, fn)] in the order of ``--estimator``, the constant baseline included."""
    others = replace(config.options, names=tuple(n for n in config.options.names if n != CONSTANT))
    resolved = iter(others.estimators())
    return [(CONSTANT, constant_estimator(config.constant_F)) if n == CONSTANT else next(resolved)
            for n in config.options.names]


# ------------------------------------------------------------------------------ one pair


def _message(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text if isinstance(exc, FvizError) else f"{type(exc).__name__}: {text}"


class PairEvaluator:
    """Evaluates pairs of one run, keeping features of recent frames (one per worker process)."""

    def __init__(self, config: RunConfig, out_dir: Path):
        from fviz.estimators.features import FeatureCache

        self.config, self.out_dir = config, Path(out_dir)
        self.source = config.selection.source()
        self.estimators = resolve_estimators(config)
        self.features = config.options.feature_config()
        self.cache = FeatureCache(self.features, max_items=config.cache_items())

    def evaluate(self, pid: PairId):
        """(Pair, PairResult) with the full payload (what inspect and triage.rrd show)."""
        from fviz.evaluate import evaluate_pair

        pair = self.source.load(pid)
        result = evaluate_pair(pair, self.estimators, self.features, self.config.norm, self.config.eval_threshold,
                               self.config.options.threshold, cache=self.cache)
        return pair, result

    def record(self, index: int, pid: PairId) -> dict[str, Any]:
        """One line of results.jsonl; never raises for a bad pair (the error is in the record)."""
        from fviz.triage import diagnose

        t0, misses = time.perf_counter(), self.cache.misses
        rec: dict[str, Any] = {"index": index, "key": pid.name, "ref": pid.to_dict(),
                               "estimators": self.config.estimator_names(), "error": None, "result": None}
        try:
            pair, result = self.evaluate(pid)
            rec["result"] = result.to_dict()
            if result.n_matches < MIN_MATCHES:
                rec["error"] = f"only {result.n_matches} matches ({MIN_MATCHES} needed)"
            rec["diagnostics"] = diagnose(pair, result)
            if self.config.full:
                save_payload(payload_path(self.out_dir, index), result)
        except Exception as exc:  # one bad pair must not stop the run
            rec["error"] = _message(exc)
        rec.update(detections=self.cache.misses - misses, seconds=time.perf_counter() - t0,
                   finished_at=time.time(), worker=os.getpid())
        return rec


# ------------------------------------------------------------------------------ payload (--full)


def payload_path(out_dir: Path, index: int) -> Path:
    return Path(out_dir) / PAYLOAD_DIR / f"{index:06d}.npz"


def save_payload(path: Path, result: PairResult) -> None:
    """The arrays log_pair needs beyond the JSON record (atomic: temporary name, then rename)."""
    arrays = {"x_a": result.matches.x_a, "x_b": result.matches.x_b, "eval_mask": result.eval_mask}
    for i, r in enumerate(result.estimators):
        if r.inliers is not None:
            arrays[f"inliers_{i}"], arrays[f"residuals_{i}"] = r.inliers, r.residuals_px
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def load_payload(path: Path, result: PairResult) -> PairResult:
    """Fill matches, the evaluation mask, inliers and residuals of a result rebuilt from its record."""
    from fviz.estimators.features import Matches

    with np.load(path) as z:
        n = len(z["x_a"])
        result.matches = Matches(np.zeros((n, 2), int), z["x_a"], z["x_b"], np.zeros(n))
        result.eval_mask = z["eval_mask"]
        for i, r in enumerate(result.estimators):
            if f"inliers_{i}" in z:
                r.inliers, r.residuals_px = z[f"inliers_{i}"], z[f"residuals_{i}"]
    return result


# ------------------------------------------------------------------------------ records


def _float(v) -> float:
    return float("nan") if v is None else float(v)


def result_from_record(rec: dict[str, Any], config: RunConfig) -> PairResult:
    """The PairResult of a record (without matches): rebuilt from its JSON, or, for a pair that failed
    before evaluation, one error entry per estimator so rows and metric series stay aligned."""
    d = rec.get("result")
    if d is None:
        return PairResult(
            pair=rec["ref"], norm=config.norm, eval_threshold_px=config.eval_threshold, F_gt=np.full((3, 3), np.nan),
            n_keypoints=(0, 0), n_matches=0, n_eval=0, timings={},
            estimators=[EstimatorResult(n, None, {}, 0.0, rec["error"]) for n in config.series_names()],
        )
    ests = [EstimatorResult(e["name"], None if e["F"] is None else np.array(e["F"]),
                            {k: _float(v) for k, v in e["metrics"].items()}, e["seconds"], e["error"])
            for e in d["estimators"]]
    return PairResult(
        pair=d["pair"], norm=d["norm"], eval_threshold_px=d["eval_threshold_px"], F_gt=np.array(d["F_gt"]),
        n_keypoints=tuple(d["n_keypoints"]), n_matches=d["n_matches"], n_eval=d["n_eval"], timings=d["timings"],
        estimators=ests, notes=d.get("notes", []),
    )


def record_rows(rec: dict[str, Any], result: PairResult) -> list[dict[str, Any]]:
    """CSV rows of a record: PairResult.rows() with the pair's index first and its pair-level error."""
    return [{"index": rec["index"], **row, "pair_error": rec["error"] or ""} for row in result.rows()]


class ResultStore:
    """results.jsonl: append-only, one record per line, flushed per pair."""

    def __init__(self, out_dir: Path):
        self.path = Path(out_dir) / RESULTS_FILE
        self._file = None

    def _scan(self) -> Iterator[tuple[int, dict[str, Any]]]:
        """(byte offset, record) of every complete, valid line."""
        if not self.path.is_file():
            return
        with open(self.path, "rb") as f:
            offset = 0
            for line in f:
                if line.endswith(b"\n"):
                    try:
                        yield offset, json.loads(line)
                    except ValueError:
                        pass
                offset += len(line)

    def latest(self) -> dict[str, tuple[int, int, tuple[str, ...]]]:
        """key -> (offset, index, estimator names) of each pair's last record."""
        return {rec["key"]: (off, rec["index"], tuple(rec["estimators"])) for off, rec in self._scan()}

    def records(self) -> Iterator[dict[str, Any]]:
        """Each pair's last record, by index, read one at a time."""
        yield from read_records([(self.path, off, index) for off, index, _ in self.latest().values()])

    def append(self, rec: dict[str, Any]) -> None:
        if self._file is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "ab")
            if self._file.tell() > 0 and not _ends_with_newline(self.path):
                self._file.write(b"\n")  # a line cut by a crash stays an (ignored) line of its own
        self._file.write((json.dumps(rec, allow_nan=True) + "\n").encode())
        self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def read_records(entries: list[tuple[Path, int, int]]) -> Iterator[dict[str, Any]]:
    """Records at (file, offset, index) entries, in index order, one at a time."""
    handles: dict[Path, Any] = {}
    try:
        for path, off, _ in sorted(entries, key=lambda e: e[2]):
            f = handles.get(path) or handles.setdefault(path, open(path, "rb"))
            f.seek(off)
            yield json.loads(f.readline())
    finally:
        for f in handles.values():
            f.close()


def _ends_with_newline(path: Path) -> bool:
    with open(path, "rb") as f:
        f.seek(-1, os.SEEK_END)
        return f.read(1) == b"\n"


def read_config(out_dir: Path) -> RunConfig | None:
    path = Path(out_dir) / RUN_FILE
    if not path.is_file():
        return None
    try:
        return RunConfig.from_dict(json.loads(path.read_text()))
    except (ValueError, KeyError, TypeError) as exc:
        raise FvizError(f"{path}: not an fviz run configuration ({exc})") from None


def write_config(out_dir: Path, config: RunConfig) -> None:
    path = Path(out_dir) / RUN_FILE
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(json.dumps(config.to_dict(), indent=2))
    os.replace(tmp, path)


# ------------------------------------------------------------------------------ execution


_WORKER: dict[str, Any] = {}


def _init_worker(config_dict: dict, out_dir: str, queue, stop) -> None:
    """Pool initializer: one evaluator per process; Ctrl-C is the main process's business."""
    import signal

    import cv2

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # already inherited; kept for other start methods
    cv2.setNumThreads(1)  # one process per core already
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass
    _WORKER.update(evaluator=PairEvaluator(RunConfig.from_dict(config_dict), Path(out_dir)), queue=queue, stop=stop)


def _run_chunk(chunk: list[tuple[int, dict]]) -> int:
    """Evaluate a contiguous chunk in a worker, streaming each record to the main process."""
    done = 0
    for index, ref in chunk:
        if _WORKER["stop"].is_set():
            break
        _WORKER["queue"].put(_WORKER["evaluator"].record(index, PairId(**{k: v for k, v in ref.items() if k != "name"})))
        done += 1
    return done


def contiguous_chunks(items: list, n: int) -> list[list]:
    """n contiguous, nearly equal blocks (none empty)."""
    n = max(1, min(n, len(items)))
    return [items[i * len(items) // n:(i + 1) * len(items) // n] for i in range(n)]


def _execute(config: RunConfig, todo: list[tuple[int, PairId]], workers: int, out_dir: Path,
             on_record: Callable[[dict], None]) -> None:
    """Evaluate ``todo``, calling ``on_record`` in this process as each pair finishes.

    One worker: in this process. Several: a process pool, one contiguous chunk per worker; on
    Ctrl-C the workers finish their current pair, whose records still reach ``on_record``.
    """
    workers = min(workers, len(todo) // MIN_PAIRS_PER_WORKER)
    if workers <= 1:
        evaluator = PairEvaluator(config, out_dir)
        for index, pid in todo:
            on_record(evaluator.record(index, pid))
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    ctx = mp.get_context("spawn")
    queue, stop = ctx.Queue(), ctx.Event()
    chunks = contiguous_chunks([(i, pid.to_dict()) for i, pid in todo], workers)
    with _single_threaded_children(), ProcessPoolExecutor(
        len(chunks), mp_context=ctx, initializer=_init_worker, initargs=(config.to_dict(), str(out_dir), queue, stop)
    ) as pool:
        with _sigint_ignored():  # the workers start (and inherit) with Ctrl-C ignored
            futures = [pool.submit(_run_chunk, c) for c in chunks]
        received = [0]
        try:
            _drain(queue, futures, on_record, received)
        except KeyboardInterrupt:
            stop.set()
            _drain(queue, futures, on_record, received)
            raise


@contextlib.contextmanager
def _sigint_ignored():
    import signal

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def _single_threaded_children():
    """Worker processes inherit one BLAS/OpenMP thread each (one process per core already)."""
    saved = {k: os.environ.get(k) for k in THREAD_ENV}
    os.environ.update({k: "1" for k in THREAD_ENV})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _drain(queue, futures, on_record: Callable[[dict], None], received: list[int]) -> None:
    """Hand records to ``on_record`` until every chunk is done and each of its records was received
    (``received[0]`` counts them across calls: a Ctrl-C interrupts the first call, a second one finishes)."""
    import queue as queue_mod

    while True:
        try:
            rec = queue.get(timeout=0.2)
        except queue_mod.Empty:
            if all(f.done() for f in futures):
                expected = sum(f.result() for f in futures)  # re-raises a crashed worker's error
                while received[0] < expected:  # records still in the pipe
                    rec = queue.get(timeout=60)
                    received[0] += 1
                    on_record(rec)
                return
            continue
        received[0] += 1
        on_record(rec)


@dataclass
class RunOutcome:
    total: int  # pairs of this run (its shard)
    reused: int  # already in results.jsonl
    computed: int  # evaluated now
    interrupted: bool
    out_dir: Path
    failed: int = 0
    detections: int = 0
    paths: dict[str, Path] = field(default_factory=dict)


def _check_resume(out_dir: Path, config: RunConfig, resume: bool) -> None:
    old = read_config(out_dir)
    has_results = (Path(out_dir) / RESULTS_FILE).is_file()
    if not resume and has_results:
        raise FvizError(f"--out-dir {out_dir} already holds a run: add --resume to continue it, or choose another folder")
    if old is not None and has_results and old.comparable() != config.comparable():
        diff = [k for k in config.comparable() if old.comparable().get(k) != config.comparable()[k]]
        raise FvizError(f"--resume: {out_dir} was run with other options (different {', '.join(diff)}); "
                        "use the same flags or another --out-dir")
    if old is not None and has_results and old.shard != config.shard:
        raise FvizError(f"--resume: {out_dir} holds shard {old.shard}, not {config.shard}")


def _progress(enabled: bool):
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("elapsed"),
                    TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(), console=Console(stderr=True),
                    disable=not enabled)


def run_eval(config: RunConfig, out_dir: str | Path, workers: int | None = None, resume: bool = False,
             progress: bool = True) -> RunOutcome:
    """Evaluate the pairs of ``config`` not yet in ``out_dir`` and regenerate the reports.

    Ctrl-C stops after the pairs in flight; the reports then cover every finished pair and
    ``outcome.interrupted`` is set (``--resume`` finishes the run).
    """
    out_dir = Path(out_dir)
    config = prepare(config)
    _check_resume(out_dir, config, resume)
    pairs = config.pairs()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FvizError(f"--out-dir {out_dir}: cannot create it ({exc.strerror})") from None
    store = ResultStore(out_dir)
    names = tuple(config.estimator_names())
    done = {key for key, (_, _, ests) in store.latest().items() if ests == names}
    todo = [(i, pid) for i, pid in pairs if pid.name not in done]
    write_config(out_dir, config)
    outcome = RunOutcome(total=len(pairs), reused=len(pairs) - len(todo), computed=0, interrupted=False, out_dir=out_dir)

    def on_record(rec: dict) -> None:
        store.append(rec)
        outcome.computed += 1
        outcome.failed += rec["error"] is not None
        outcome.detections += rec["detections"]
        bar.advance(task)

    workers = (os.cpu_count() or 1) if workers is None else workers
    with _progress(progress) as bar:
        task = bar.add_task("eval", total=len(pairs), completed=outcome.reused)
        try:
            _execute(config, todo, workers, out_dir, on_record)
        except KeyboardInterrupt:
            outcome.interrupted = True
        finally:
            store.close()
    outcome.paths = write_reports(out_dir, config)
    return outcome


# ------------------------------------------------------------------------------ reports


def _columns(rows_iter: Iterable[dict[str, Any]]) -> list[str]:
    cols: dict[str, None] = {}
    for row in rows_iter:
        cols.update(dict.fromkeys(row))
    return list(cols)


def iter_rows(out_dir: Path, config: RunConfig) -> Iterator[tuple[dict[str, Any], PairResult, list[dict[str, Any]]]]:
    """(record, its PairResult, its CSV rows) of each pair, by index."""
    for rec in ResultStore(out_dir).records():
        result = result_from_record(rec, config)
        yield rec, result, record_rows(rec, result)


def _arrow_schema(columns: list[str]):
    import pyarrow as pa

    return pa.schema([(c, pa.string() if c in TEXT_COLUMNS else pa.int64() if c in INT_COLUMNS else pa.float64())
                      for c in columns])


class _Stats:
    """Finite values per (estimator, metric) for the summary; failures counted per estimator."""

    def __init__(self, keys: Iterable[str]):
        self.keys = frozenset(keys)
        self.values: dict[tuple[str, str], array] = {}
        self.failed: dict[str, int] = {}
        self.pairs = self.pair_errors = 0
        self.order: dict[str, None] = {}

    def add(self, rec: dict[str, Any], rows: list[dict[str, Any]]) -> None:
        self.pairs += 1
        self.pair_errors += rec["error"] is not None
        for row in rows:
            est = row["estimator"]
            self.order[est] = None
            if row["error"] or rec["error"]:
                self.failed[est] = self.failed.get(est, 0) + 1
            for key in self.keys:
                v = row.get(key)
                if isinstance(v, float) and math.isfinite(v):
                    self.values.setdefault((est, key), array("d")).append(v)

    def get(self, est: str, key: str) -> np.ndarray:
        return np.asarray(self.values.get((est, key), []), dtype=np.float64)


def write_reports(out_dir: Path, config: RunConfig) -> dict[str, Path]:
    """metrics.csv, metrics.parquet, summary.md and eval.rrd from results.jsonl (each written atomically)."""
    out_dir = Path(out_dir)
    columns = _columns(row for _, _, rows in iter_rows(out_dir, config) for row in rows)
    stats = _write_tables(out_dir, config, columns)
    paths = {"csv": out_dir / CSV_FILE, "parquet": out_dir / PARQUET_FILE}
    paths["summary"] = write_summary(out_dir / SUMMARY_FILE, config, stats)
    paths["rrd"] = write_recording(out_dir / RRD_FILE, out_dir, config)
    return paths


def _write_tables(out_dir: Path, config: RunConfig, columns: list[str], batch: int = 2000) -> _Stats:
    import pyarrow as pa
    import pyarrow.parquet as pq

    csv_path, pq_path = out_dir / CSV_FILE, out_dir / PARQUET_FILE
    csv_tmp, pq_tmp = tmp_path(csv_path), tmp_path(pq_path)
    schema, stats, pending = _arrow_schema(columns), _Stats(SUMMARY_METRICS + PAPER_COLUMNS), []
    with open(csv_tmp, "w", newline="") as f, pq.ParquetWriter(pq_tmp, schema) as pw:
        writer = csv.DictWriter(f, columns, restval="")
        writer.writeheader()

        def flush():
            pw.write_table(pa.Table.from_pylist(pending, schema=schema))
            pending.clear()

        for rec, _, rows in iter_rows(out_dir, config):
            stats.add(rec, rows)
            writer.writerows(rows)
            pending.extend(_typed(row, columns) for row in rows)
            if len(pending) >= batch:
                flush()
        flush()
    os.replace(csv_tmp, csv_path)
    os.replace(pq_tmp, pq_path)
    return stats


def _typed(row: dict[str, Any], columns: list[str]) -> dict[str, Any]:
    out = {}
    for c in columns:
        v = row.get(c)
        if c in TEXT_COLUMNS:
            out[c] = None if v is None else str(v)
        elif c in INT_COLUMNS:
            out[c] = None if v is None else int(v)
        else:
            out[c] = None if v is None or v == "" else float(v)
    return out


def _fmt(v: float) -> str:
    return "n/a" if not math.isfinite(v) else f"{v:.4g}"


def _display(est: str) -> str:
    return "ground truth" if est == GT_NAME else est


def summary_markdown(config: RunConfig, stats: _Stats) -> str:
    """Per-estimator statistics of the key metrics and the paper-style EPI table."""
    ests = list(stats.order) or config.series_names()
    o = config.options
    lines = [
        "# fviz eval",
        "",
        f"{config.selection.describe()}" + (f", shard {config.shard[0]}/{config.shard[1]}" if config.shard else "") + ".",
        f"{stats.pairs} pairs ({stats.pair_errors} failed as a whole); features {o.features} (max {o.max_keypoints}, ratio {o.ratio}"
        f"{', mutual' if o.mutual else ''}); robust threshold {o.threshold} px; evaluation matches: GT symmetric epipolar "
        f"distance < {config.eval_threshold} px.",
        f"EPI-ABS / EPI-SQR (`epi_abs`, `epi_sqr`) are per-pair **means** over the evaluation matches, on F normalized by "
        f"**{config.norm.upper()}**; distances in px. Statistics below are over the pairs where the estimator succeeded.",
        "",
        "## Per estimator",
    ]
    for key in SUMMARY_METRICS:
        lines += ["", f"### {key}", "", "| estimator | ok | failed | mean | median | " + " | ".join(f"p{p}" for p in PERCENTILES) + " |",
                  "|---|---|---|---|---|" + "---|" * len(PERCENTILES)]
        for est in ests:
            v = stats.get(est, key)
            vals = [v.mean(), np.median(v), *(np.percentile(v, p) for p in PERCENTILES)] if len(v) else [math.nan] * (2 + len(PERCENTILES))
            lines.append(f"| {_display(est)} | {stats.pairs - stats.failed.get(est, 0)} | {stats.failed.get(est, 0)} | "
                         + " | ".join(_fmt(x) for x in vals) + " |")
    lines += [
        "",
        "## Paper-style table",
        "",
        "Means over pairs of the per-pair EPI-ABS and EPI-SQR (themselves means over the evaluation matches), "
        "F normalized by the norm named in each column (FBN: Frobenius norm, ABS: largest absolute entry, "
        "ETR: F33; n/a where undefined, e.g. ETR on rectified stereo pairs where F33 = 0).",
        "",
        "| estimator | " + " | ".join(f"EPI-ABS {n.upper()} | EPI-SQR {n.upper()}" for n in PAPER_NORMS) + " |",
        "|---|" + "---|---|" * len(PAPER_NORMS),
    ]
    for est in ests:
        vals = [stats.get(est, c) for c in PAPER_COLUMNS]
        lines.append(f"| {_display(est)} | " + " | ".join(_fmt(v.mean()) if len(v) else "n/a" for v in vals) + " |")
    if CONSTANT in ests:
        lines += ["", f"`{CONSTANT}`: one F for every pair, the mean ground-truth F of the selection (FBN-normalized, "
                  "sign-aligned, averaged); a low error there reveals dataset bias, not estimation skill."]
    return "\n".join(lines) + "\n"


def write_summary(path: Path, config: RunConfig, stats: _Stats) -> Path:
    return write_text(path, summary_markdown(config, stats))


def _light_blueprint():
    import rerun.blueprint as rrb

    from fviz.record import layout as L
    from fviz.record.writer import SCALAR_METRICS

    return rrb.Blueprint(rrb.Horizontal(
        rrb.Grid(*[rrb.TimeSeriesView(origin=L.metric(k), name=k) for k in SCALAR_METRICS]),
        rrb.TextDocumentView(origin=L.SUMMARY, name="summary"),
        column_shares=[3, 2],
    ), collapse_panels=True)


def _pair_text(rec: dict[str, Any], result: PairResult) -> str:
    """The per-pair Markdown: inspect's summary, or the reason a pair failed as a whole."""
    from fviz.record.writer import pair_markdown

    if rec.get("result") is None:
        return f"# {rec['key']}\n\n**failed**: {rec['error']}\n"
    text = pair_markdown(result)
    return text + (f"\n\n**pair failed**: {rec['error']}\n" if rec["error"] else "")


def log_summary_pair(rec_stream, index: int, rec: dict[str, Any], result: PairResult) -> None:
    """The light per-pair payload at ``pair`` = index: name, summary, errors and metric values."""
    import rerun as rr

    from fviz.record import layout as L
    from fviz.record.writer import log_metrics

    rec_stream.set_time(L.TIMELINE, sequence=index)
    rec_stream.log(L.PAIR_INFO, rr.TextDocument(result.pair.get("name", rec["key"])))
    rec_stream.log(L.SUMMARY, rr.TextDocument(_pair_text(rec, result), media_type="text/markdown"))
    for r in result.estimators:
        if r.error:
            rec_stream.log(L.error(r.name), rr.TextLog(f"{r.name} failed: {r.error}", level="ERROR"))
    log_metrics(rec_stream, result)


def write_recording(path: Path, out_dir: Path, config: RunConfig) -> Path:
    """eval.rrd: every pair on the ``pair`` timeline; with ``--full`` (and a saved payload) the whole
    inspect payload, images re-read from the source."""
    from fviz.record import layout as L
    from fviz.record.writer import RecordingWriter, log_pair, log_static

    source = config.selection.source() if config.full else None
    blueprint = _light_blueprint()
    if config.full:
        first = next((r["result"]["pair"] for r in ResultStore(out_dir).records() if r.get("result")), None)
        if first is not None:
            blueprint = L.blueprint(tuple(first["size_a"]), tuple(first["size_b"]))
    with RecordingWriter(path, "fviz-eval", blueprint) as w:
        log_static(w.rec, config.series_names())
        for rec, result, _ in iter_rows(out_dir, config):
            payload = payload_path(out_dir, rec["index"])
            if source is not None and rec.get("result") is not None and payload.is_file():
                pair = source.load(PairId(**{k: v for k, v in rec["ref"].items() if k != "name"}))
                log_pair(w.rec, rec["index"], pair, load_payload(payload, result))
            else:
                log_summary_pair(w.rec, rec["index"], rec, result)
    return path


# ------------------------------------------------------------------------------ merge


def merge_runs(dirs: list[Path], out_dir: Path) -> RunOutcome:
    """Merge the results of shards (or any runs of one configuration) into ``out_dir``."""
    import shutil

    configs = []
    for d in dirs:
        c = read_config(d)
        if c is None or not (Path(d) / RESULTS_FILE).is_file():
            raise FvizError(f"merge: {d} holds no fviz run ({RUN_FILE} and {RESULTS_FILE} expected)")
        configs.append(c)
    first = configs[0]
    for d, c in zip(dirs, configs):
        if c.comparable() != first.comparable() or c.estimator_names() != first.estimator_names():
            raise FvizError(f"merge: {d} was run with other options than {dirs[0]}")
    out_dir = Path(out_dir)
    if (out_dir / RESULTS_FILE).exists():
        raise FvizError(f"--out-dir {out_dir} already holds a run: choose an empty folder")
    out_dir.mkdir(parents=True, exist_ok=True)
    config = replace(first, shard=None)
    latest: dict[str, tuple[Path, int, int]] = {}  # key -> (results file, offset, index); later dirs win
    for d in dirs:
        store = ResultStore(d)
        latest.update({key: (store.path, off, index) for key, (off, index, _) in store.latest().items()})
    store, failed = ResultStore(out_dir), 0
    for rec in read_records(list(latest.values())):
        store.append(rec)
        failed += rec["error"] is not None
        payload = payload_path(Path(latest[rec["key"]][0]).parent, rec["index"])
        if payload.is_file():
            payload_path(out_dir, rec["index"]).parent.mkdir(exist_ok=True)
            shutil.copyfile(payload, payload_path(out_dir, rec["index"]))
    store.close()
    write_config(out_dir, config)
    outcome = RunOutcome(total=len(config.pairs()), reused=len(latest), computed=0, interrupted=False,
                         out_dir=out_dir, failed=failed)
    outcome.paths = write_reports(out_dir, config)
    return outcome
