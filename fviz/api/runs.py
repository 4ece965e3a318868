"""Runs from Python: evaluate a selection of pairs into a run folder, triage it, compare two estimators or two runs,
make the paper's table, read a run back. ``fviz eval``, ``triage``, ``compare``, ``table`` and ``merge`` are clients
of these functions (flag parsing, one call, printing)::

    import fviz

    pairs = fviz.select("data/kitti", sequence="00", frames=(0, 4), kinds=("stereo", "temporal"))
    run = fviz.evaluate_run(pairs, "runs/a", estimators=("8point", "magsac"), workers=1)
    triage = fviz.triage_run(run, by="8point", top=5)             # triage.md, triage.rrd
    c = fviz.compare_runs(run, estimators=("8point", "magsac"))   # compare.md, compare.rrd
    md, csv = fviz.run_table(run)                                 # table.md, table.csv
    run = fviz.read_run("runs/a")                                 # its configuration, records, summary

Parameters are Python values (paths, tuples, numbers, arrays); bad input raises :class:`fviz.errors.FvizError`
with a one-line message that starts with the parameter's name.
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator, Sequence

from fviz.api.names import python_errors, word
from fviz.api.sources import KITTI_ROOT_ENV
from fviz.data.selection import Selection
from fviz.errors import FvizError
from fviz.run.config import SUMMARY_JSON, RunConfig
from fviz.run.store import RunOutcome

if TYPE_CHECKING:  # pragma: no cover
    from fviz.triage import TriageOutcome

__all__ = ["Selection", "Run", "Compared", "select", "evaluate_run", "triage_run", "compare_runs", "run_table",
           "read_run", "merge_runs"]

COMPARE_FILE = "compare.md"  # fviz.compare.COMPARE_FILE (checked in tests)


def __getattr__(name: str):
    if name == "FEATURES_FILE":  # the run's feature cache (the command line names it), without importing OpenCV
        from fviz.run.hloc_cache import FEATURES_FILE

        return FEATURES_FILE
    raise AttributeError(name)


def default_estimators() -> tuple[str, ...]:
    """A run's estimators when none are named: inspect's (8point, ransac, magsac) and ``ahead``."""
    from fviz.estimators.registry import AHEAD, DEFAULT_ESTIMATORS

    return (*DEFAULT_ESTIMATORS, AHEAD)


# ---------------------------------------------------------------------------------------------- which pairs


@python_errors
def select(
    kitti_root: str | os.PathLike | None = None,
    *,
    sequence: str | None = None,
    drive: str | None = None,
    kinds: str | Sequence[str] = ("stereo",),
    steps: int | Sequence[int] = (1,),
    cams: tuple[int, int] | None = None,
    frames: tuple[int | None, int | None] | range | None = None,
    seeds: tuple[int, int] | range | None = None,
    synthetic: bool | None = None,
    pairs: str | os.PathLike | None = None,
    images: str | os.PathLike | None = None,
    colmap: str | os.PathLike | None = None,
    min_shared: int = 100,
    matches: str | os.PathLike | None = None,
    gt_matches: str | os.PathLike | None = None,
    image_a: str | os.PathLike | None = None,
    image_b: str | os.PathLike | None = None,
    K: Any = None,
    K_a: Any = None,
    K_b: Any = None,
    T_ab: Any = None,
    F_gt: Any = None,
) -> Selection:
    """Which pairs a run evaluates (one source):

    - KITTI under ``kitti_root`` (default ``$FVIZ_KITTI_ROOT``): odometry ``sequence`` or raw ``drive``, pairs of
      ``kinds`` ("stereo", "temporal" at each of ``steps``) over ``frames`` = (start, end), end exclusive (None: the
      sequence's ends), cameras ``cams`` (default 0, 1 for stereo, 0, 0 for temporal);
    - ``seeds`` = (a, b): synthetic scenes a .. b-1 (no dataset needed), one pair per seed and kind;
    - a pairs file ``pairs`` (names relative to ``images``) or a COLMAP model ``colmap`` (its image pairs sharing
      ``min_shared`` points, or those of ``pairs``), ``frames`` selecting its lines;
    - two images ``image_a``, ``image_b`` with, optionally, ``K`` (both) or ``K_a``, ``K_b`` ((3, 3) or fx, fy, cx,
      cy), ``T_ab`` ((3, 4) or (4, 4): x_b = R x_a + t) or ``F_gt`` (3, 3), as arrays, numbers or a file of them.

    ``matches`` replaces fviz's features with yours (hloc h5, SuperGlue npz, text); ``gt_matches`` are ground-truth
    correspondences the metrics are computed on.

    Returns:
        A :class:`fviz.run.config.Selection` (frozen; stored in the run's run.json), for :func:`evaluate_run`.
    """
    user = any(v is not None for v in (pairs, colmap, image_a, image_b))
    synthetic = seeds is not None if synthetic is None else synthetic
    root = None
    if not synthetic and not user:
        root = _absolute(kitti_root or os.environ.get(KITTI_ROOT_ENV) or _no_root())
    elif kitti_root is not None:
        root = _absolute(kitti_root)  # refused by Selection, with the flag named
    return Selection(
        pairs=_absolute(pairs), images=_absolute(images), colmap=_absolute(colmap), min_shared=min_shared,
        matches=_absolute(matches), gt_matches=_absolute(gt_matches), image_a=_absolute(image_a),
        image_b=_absolute(image_b), K=_numbers(K), K_a=_numbers(K_a), K_b=_numbers(K_b), T_ab=_file_or_numbers(T_ab),
        F_gt=_file_or_numbers(F_gt), kitti_root=root, sequence=sequence, drive=drive,
        kinds=(kinds,) if isinstance(kinds, str) else tuple(kinds), steps=(steps,) if isinstance(steps, int) else tuple(steps),
        cams=None if cams is None else tuple(cams), frames=_range(frames), synthetic=synthetic,
        seeds=None if seeds is None else _range(seeds))


def _no_root():
    raise FvizError(f"--kitti-root: missing (or set ${KITTI_ROOT_ENV}); use --synthetic for a scene that needs no dataset")


def _absolute(path) -> str | None:
    """An absolute path (a run may be resumed from another folder)."""
    return None if path is None else os.path.abspath(Path(path).expanduser())


def _range(r) -> tuple[int | None, int | None]:
    if r is None:
        return (None, None)
    if isinstance(r, range):
        return (r.start, r.stop)
    return tuple(r)


def _numbers(value: Any) -> str | None:
    """A matrix as the comma list run.json stores (text, a file's name: as given)."""
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    import numpy as np

    return ",".join(repr(float(v)) for v in np.asarray(value, dtype=float).ravel())


def _file_or_numbers(value: Any) -> str | None:
    """T_ab / F_gt: a file's absolute path (the run may be resumed from elsewhere), or the numbers."""
    text = _numbers(value)
    return os.path.abspath(text) if text is not None and Path(text).is_file() else text


# ---------------------------------------------------------------------------------------------- a run


@dataclass
class Run:
    """A run folder read back: its configuration and, after :func:`evaluate_run`, what that call did."""

    out_dir: Path
    config: RunConfig
    outcome: RunOutcome | None = None  # pairs reused / evaluated / failed, interrupted, report paths

    @property
    def estimators(self) -> list[str]:
        """The estimators' names, in the order of the run (the ground truth ``gt`` not included)."""
        return self.config.estimator_names()

    @property
    def interrupted(self) -> bool:
        """Ctrl-C stopped :func:`evaluate_run`: the reports cover the finished pairs (finish with resume=True)."""
        return bool(self.outcome and self.outcome.interrupted)

    @property
    def summary(self) -> dict[str, Any]:
        """summary.json: the standard figures per estimator (pose AUC, NSGD recall, median SED, ...), failures."""
        path = self.out_dir / SUMMARY_JSON
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            return {}

    def records(self) -> Iterator[dict[str, Any]]:
        """Each pair's record of results.jsonl (its metrics per estimator, F's, diagnostics), in pair order."""
        from fviz.run.store import ResultStore

        yield from ResultStore(self.out_dir).records()

    def figures(self) -> tuple[str, list[str], list[list[str]]] | None:
        """The standard figures as (title, header, rows), as ``fviz eval`` prints them (the pose AUC over every pair;
        where some pair's pose is undefined, also over the pairs with a pose and their count, apart); None before any
        report."""
        from fviz.run.reports import UNDEFINED_COLUMN, WITH_POSE
        from fviz.verdicts import ERRORS, fails_column

        doc = self.summary
        if not doc:
            return None
        fmt = lambda v: "n/a" if v is None else f"{v:.3g}"  # noqa: E731
        first = next(iter(doc["estimators"].values()), {"pose_auc": {}})
        apart = any(f.get("pose_undefined") for f in doc["estimators"].values())  # say the undefined pairs apart
        extra = [f"AUC@{'/'.join(first['pose_auc'])}° ({WITH_POSE})", UNDEFINED_COLUMN] if apart else []
        header = ["estimator", *(f"AUC@{k}°" for k in first["pose_auc"]), *extra, "NSGD recall", "med SED px",
                  "med Sampson px", ERRORS, fails_column()]
        rows = []
        for name, f in doc["estimators"].items():
            cells = ["/".join(fmt(v) for v in f.get("pose_auc_with_pose", {}).values()),
                     f"{f.get('pose_undefined', 0)}/{f['pairs']}"] if apart else []
            rows.append([name + (" (oracle)" if f["oracle"] else ""), *(fmt(v) for v in f["pose_auc"].values()), *cells,
                         fmt(f["nsgd_recall"]), fmt(f["sed_median"]), fmt(f["sampson_median"]),
                         f"{f['errors']}/{f['pairs']}", f"{f['fails']}/{f['pairs']}"])
        return f"{doc['selection']}: {doc['pairs']} pairs", header, rows

    def failure_lines(self) -> list[str]:
        """The run's failures grouped by cause, one line each, and a ground truth biased over the run (a note)."""
        from fviz.failures import failure_lines

        doc = self.summary
        lines = failure_lines(doc.get("failures")) if doc else []
        return lines + ([f"note: {doc['gt_bias']['text']}"] if doc.get("gt_bias") else [])


def _folder(run: Run | str | os.PathLike) -> Path:
    return run.out_dir if isinstance(run, Run) else Path(run)


@python_errors
def read_run(out_dir: str | os.PathLike) -> Run:
    """The run in ``out_dir`` (an :func:`evaluate_run` or ``fviz eval`` folder): its configuration, records, summary."""
    from fviz.run import read_config

    folder = Path(out_dir)
    config = read_config(folder)
    if config is None:
        raise FvizError(f"--out-dir {out_dir}: no run there ({'no run.json' if folder.is_dir() else 'no such folder'})")
    return Run(folder, config)


def writable_folder(path: Path, flag: str = "--out-dir") -> None:
    """A one-line error when ``path`` (or, before it exists, its nearest existing parent) is not a folder fviz can
    write to; nothing is created here."""
    import tempfile

    probe = next((p for p in (path, *path.absolute().parents) if p.exists()), None)
    if probe is None or not probe.is_dir():
        raise FvizError(f"{flag} {path}: {probe} is not a folder")
    try:
        tempfile.TemporaryFile(dir=probe).close()
    except OSError as exc:
        where = "" if probe == path else f" (its parent {probe})"
        raise FvizError(f"{flag} {path}: cannot write there{where}: {exc.strerror or exc}") from None


def worker_count(requested: int | None) -> int:
    """``workers``, capped at the CPU cores with a note (more processes only cost memory); default: the cores."""
    from fviz.run.config import MIN_PAIRS_PER_WORKER

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if requested is not None and requested > cores:
        print(f"note: {word('--workers')} {requested} capped at {cores}, the CPU cores here (and at one worker per "
              f"{MIN_PAIRS_PER_WORKER} pairs to evaluate)", file=sys.stderr)
    return min(requested or cores, cores)


def run_config(
    out_dir: str | os.PathLike,
    selection: Selection | None = None,
    *,
    estimators: Sequence[str] | None = None,
    features: str = "sift",
    max_keypoints: int = 2000,
    ratio: float = 0.8,
    mutual: bool = True,
    threshold: float | Sequence[float] | str = 1.0,
    confidence: float = 0.999,
    max_iters: int = 10000,
    seed: int = 0,
    norm: str = "fbn",
    eval_threshold: float = 2.0,
    estimator_timeout: float = 600.0,
    shard: tuple[int, int] | str | None = None,
    full: bool = False,
    resume: bool = False,
) -> RunConfig:
    """The configuration of a run (:func:`evaluate_run`'s arguments); without ``selection``, the run already in
    ``out_dir`` as it was configured (``estimators``, ``shard``, ``full`` and ``estimator_timeout`` applied to it)."""
    from dataclasses import replace

    from fviz.api.pairs import threshold_specs
    from fviz.estimators.options import EstimatorOptions
    from fviz.run import read_config

    existing = None if selection is not None else read_config(Path(out_dir))
    if existing is None and selection is None:
        if resume or not os.environ.get(KITTI_ROOT_ENV):
            what = "no such folder" if not Path(out_dir).exists() else "no run.json there"
            raise FvizError(f"--out-dir {out_dir}: no run to {'resume' if resume else 'use'} ({what}); "
                            "select pairs (--kitti-root/--sequence, or --synthetic --seeds A:B) to start one")
        selection = select()
    names, value = threshold_specs(tuple(estimators or (existing.options.names if existing else default_estimators())),
                                   threshold)
    shard = _shard(shard)
    if existing is not None:
        if estimators:
            existing = replace(existing, options=replace(existing.options, names=names))
        return replace(existing, shard=shard or existing.shard, full=existing.full or full,
                       estimator_timeout=estimator_timeout)
    opts = EstimatorOptions(names, features, max_keypoints, ratio, mutual, value, confidence, max_iters, seed)
    return RunConfig(selection, opts, norm, eval_threshold, full, shard, estimator_timeout=estimator_timeout)


def _options(options: dict[str, Any]) -> dict[str, Any]:
    """``**options`` of :func:`evaluate_run` / :func:`triage_run`: those of :func:`run_config`, else a one-line error."""
    import inspect

    known = [p for p in inspect.signature(run_config).parameters if p not in ("out_dir", "selection", "resume")]
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise FvizError(f"{unknown[0]}: not an option of a run (options: {', '.join(known)})")
    return options


def _shard(shard: tuple[int, int] | str | None) -> tuple[int, int] | None:
    from fviz.run import parse_shard

    if shard is None:
        return None
    return parse_shard(shard if isinstance(shard, str) else "/".join(map(str, shard)))


# ---------------------------------------------------------------------------------------------- evaluate, triage


@python_errors
def evaluate_run(
    selection: Selection | None,
    out_dir: str | os.PathLike,
    *,
    estimators: Sequence[str] | None = None,
    workers: int | None = None,
    resume: bool = False,
    progress: bool = False,
    **options: Any,
) -> Run:
    """Evaluate every pair of ``selection`` with every estimator into the run folder ``out_dir`` (``fviz eval``).

    Args:
        selection: the pairs (:func:`select`); None: the run already in ``out_dir``, as it was configured.
        out_dir: the run folder: run.json, results.jsonl, metrics.csv / .parquet, summary.md / .json, eval.rrd.
        estimators: names ("8point", "ransac", "magsac", "lmeds", "poselib", "deep:PATH", "ahead", "mean:01",
            "oracle-mean", ...); default 8point, ransac, magsac and ahead (with ``selection=None``: the run's).
        workers: processes (default: the CPU cores; at most one per 4 pairs to evaluate).
        resume: continue the run in ``out_dir``: finished pairs are not evaluated again.
        progress: a progress bar on stderr.
        **options: the estimators' and the evaluation's settings, as :func:`fviz.inspect_pair` takes them:
            ``features``, ``max_keypoints``, ``ratio``, ``mutual``, ``threshold`` (px, a list of them or "sweep"),
            ``confidence``, ``max_iters``, ``seed``, ``norm``, ``eval_threshold``; and ``estimator_timeout`` (s),
            ``shard`` ((i, n): block i of n), ``full`` (every pair's images and plots in eval.rrd: large).

    Returns:
        The :class:`Run` (``outcome``: pairs reused, evaluated, failed; ``interrupted`` after Ctrl-C).
    """
    from fviz.run import read_config, run_eval

    writable_folder(Path(out_dir))
    config = run_config(out_dir, selection, estimators=estimators, resume=resume, **_options(options))
    outcome = run_eval(config, out_dir, worker_count(workers), resume, progress)
    return Run(Path(out_dir), read_config(Path(out_dir)) or config, outcome)


@python_errors
def triage_run(
    run: Run | str | os.PathLike,
    selection: Selection | None = None,
    *,
    by: str | None = None,
    metric: str = "sed_median",
    top: int = 20,
    workers: int | None = None,
    progress: bool = False,
    **options: Any,
) -> TriageOutcome:
    """Rank a run's pairs worst first by ``metric`` of estimator ``by``, with likely causes, and find the estimators
    that ignore their input or do worse than a baseline (``fviz triage``): triage.md and triage.rrd in the run folder.

    What the run lacks is evaluated first (resume semantics): ``selection`` and ``**options`` as
    :func:`evaluate_run` takes them; without them the run is triaged as it was configured.

    Args:
        run: a :class:`Run` or its folder.
        by: the estimator whose metric ranks the pairs (default: the run's first estimator).
        metric: e.g. "sed_median", "pose_err_deg", "nsgd", "inlier_ratio" (worst first).
        top: pairs listed in triage.md and recorded in triage.rrd.

    Returns:
        A :class:`fviz.triage.TriageOutcome`: ``ranked`` (rank, key, value, tags per pair), ``findings`` per
        estimator, ``by``, ``markdown`` and ``recording`` (paths), ``eval`` (the evaluation's outcome).
    """
    from fviz.lock import locked
    from fviz.triage import run_triage

    out_dir = _folder(run)
    writable_folder(out_dir)
    config = run_config(out_dir, selection, **_options(options))  # before the lock, which creates out_dir
    with locked(out_dir):  # eval inside and triage's own reports: one run owns the folder
        return run_triage(config, out_dir, by, metric, top, worker_count(workers), progress)


# ---------------------------------------------------------------------------------------------- compare, table, merge


@dataclass
class Compared:
    """:func:`compare_runs`' result: the comparison and the files written. Its counts read through:
    ``wins``, ``losses``, ``ties``, ``only_a_fails``, ``only_b_fails``, ``values``, ``wilcoxon()``, ..."""

    comparison: Any  # fviz.compare.Comparison
    markdown: Path
    recording: Path
    replaced: bool = False  # an earlier comparison's file was replaced (force=True)

    def __getattr__(self, name: str) -> Any:
        if name == "comparison":
            raise AttributeError(name)
        return getattr(self.comparison, name)

    def rows(self) -> list[tuple[str, str]]:
        """(what, value) lines of the summary ``fviz compare`` prints: wins, losses, ties, fails, Wilcoxon's p."""
        from fviz.compare import summary_rows

        return summary_rows(self.comparison)


@python_errors
def compare_runs(
    a: Run | str | os.PathLike,
    b: Run | str | os.PathLike | None = None,
    *,
    estimators: str | tuple[str, str],
    metric: str = "sed_median",
    fail_threshold: float | None = None,
    tie: float = 0.0,
    tie_rel: float = 0.05,
    out: str | os.PathLike | None = None,
    force: bool = False,
) -> Compared:
    """Two estimators of one run, or one estimator of two runs, pair by pair (``fviz compare``): wins, losses and
    ties, Wilcoxon's signed-rank test, the pairs where only one fails; compare.md and compare.rrd.

    Args:
        a: a :class:`Run` or its folder.
        b: a second run (then ``estimators`` is one name, or one name per run); None: two estimators of ``a``.
        estimators: ("8point", "magsac") on one run; "magsac" (or one name per run) on two.
        metric: the metric compared, e.g. "sed_median", "pose_err_deg", "nsgd", "inlier_ratio".
        fail_threshold: a value worse than this fails the pair (default: the metric's own threshold).
        tie: differences up to this (in the metric's unit) are ties.
        tie_rel: differences up to this fraction of the larger value are ties.
        out: the Markdown file (default: compare.md in ``a``'s folder).
        force: replace an existing file that holds another comparison.
    """
    from fviz.compare import Side, compare, recording_path, write_compare

    names = (estimators,) * 2 if isinstance(estimators, str) else tuple(estimators)
    if len(names) != 2 or (b is None and isinstance(estimators, str)):
        raise FvizError(f"estimators {estimators!r}: two names on one run, one name (or one per run) on two runs")
    sides = Side(_folder(a), names[0]), Side(_folder(a if b is None else b), names[1])
    path = Path(out) if out is not None else _folder(a) / COMPARE_FILE
    writable_folder(path.parent, "--out" if out is not None else "--out-dir")
    c = compare(*sides, metric=metric, fail_threshold=fail_threshold, tie=tie, tie_rel=tie_rel)
    path, replaced = write_compare(c, path, force)
    return Compared(c, path, recording_path(path), replaced)


@python_errors
def run_table(run: Run | str | os.PathLike) -> tuple[Path, Path]:
    """The paper's Table 1 of a run (``fviz table``): EPI-ABS / EPI-SQR per norm for each network variant and
    estimator, and the standard figures. -> (table.md, table.csv), written in the run folder."""
    from fviz.table import write_table

    return write_table(_folder(run))


@python_errors
def merge_runs(dirs: Sequence[str | os.PathLike], out_dir: str | os.PathLike) -> Run:
    """Join the run folders of shards (``evaluate_run(..., shard=(i, n))``) into one run with all reports
    (``fviz merge``)."""
    from fviz.run import merge_runs as merge

    writable_folder(Path(out_dir))
    from fviz.run import read_config

    outcome = merge([Path(d) for d in dirs], Path(out_dir))
    return Run(Path(out_dir), read_config(Path(out_dir)), outcome)
