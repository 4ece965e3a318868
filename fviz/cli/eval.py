"""``fviz eval``: every pair of a selection, N estimators, one run folder; ``fviz merge``: join shards.

Selection: ``--kitti-root`` with ``--sequence`` / ``--drive``, ``--pair`` and ``--step`` (repeatable or
comma lists), ``--cams``, ``--frames START:END`` (END exclusive, either side may be left out); or
``--synthetic --seeds A:B``. Outputs in ``--out-dir`` (see :mod:`fviz.run`): results.jsonl (the
source of truth, appended per pair), metrics.csv / .parquet, summary.md, eval.rrd. eval.rrd holds
metric series, summaries and errors per pair; ``--full`` adds every pair's images, keypoints,
epipolar lines and plots (as ``inspect``), which for a whole KITTI sequence means gigabytes.

The shared run options are declared once here (:data:`RUN_PARAMS`) and added to any command by
:func:`run_command` (``triage`` uses them too).
"""

from __future__ import annotations

import inspect
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Callable, Optional

import typer

from fviz import api
from fviz.cli import options as o
from fviz.errors import FvizError

Pairs = Annotated[Optional[list[str]], typer.Option("--pair", help="stereo and/or temporal (repeatable or comma list; default stereo).")]
Steps = Annotated[Optional[list[str]], typer.Option("--step", help="Frame steps of temporal pairs (repeatable or comma list; default 1).")]
Frames = Annotated[Optional[str], typer.Option("--frames", help="Frame range START:END of the pairs' cameras (with --pairs / --colmap: of the listed pairs, from 0), END exclusive (default: all).")]
Seeds = Annotated[Optional[str], typer.Option("--seeds", help="With --synthetic: scene seeds A:B (A .. B-1), one pair per seed.")]
OutDir = Annotated[Path, typer.Option("--out-dir", help="Run folder: results.jsonl, metrics.csv/.parquet, summary.md, eval.rrd.")]
Workers = Annotated[Optional[int], typer.Option("--workers", help="Worker processes (default: CPU count; at most the CPU count, and one per 4 pairs to evaluate).",
                                               callback=o.checked("--workers", lambda n: n >= 1, "must be >= 1"))]
Resume = Annotated[bool, typer.Option("--resume", help="Continue the run in --out-dir; finished pairs are not recomputed.")]
Shard = Annotated[Optional[str], typer.Option("--shard", help="i/n: run only block i of n contiguous blocks of pairs, counting from 0 (0/4 .. 3/4; join with fviz merge).")]
Full = Annotated[bool, typer.Option("--full", help="Record every pair's images, keypoints and plots in eval.rrd (large).")]
Progress = Annotated[bool, typer.Option("--progress/--no-progress", help="Progress bar with ETA on stderr.")]


DEFAULT_OUT_DIR = Path("runs/eval")


def _run_options(
    kitti_root: o.KittiRoot = None,
    sequence: o.Sequence_ = None,
    drive: o.Drive = None,
    pair_kind: Pairs = None,
    step: Steps = None,
    cams: o.Cams = None,
    frames: Frames = None,
    synthetic: o.Synthetic = False,
    seeds: Seeds = None,
    pairs: o.PairsFile = None,
    images: o.ImagesDir = None,
    colmap: o.Colmap = None,
    min_shared: o.MinShared = 100,
    matches: o.MatchesFile = None,
    gt_matches: o.GtMatches = None,
    image_a: o.ImageA = None,
    image_b: o.ImageB = None,
    K: o.KBoth = None,
    K_a: o.KA = None,
    K_b: o.KB = None,
    T_ab: o.TAB = None,
    F_gt: o.FGT = None,
    estimator: o.Estimators = None,
    features: o.Features = "sift",
    max_keypoints: o.MaxKeypoints = 2000,
    ratio: o.Ratio = 0.8,
    mutual: o.Mutual = True,
    threshold: o.Threshold = "1.0",
    confidence: o.Confidence = 0.999,
    max_iters: o.MaxIters = 10000,
    seed: o.Seed = 0,
    norm: o.Norm = "fbn",
    eval_threshold: o.EvalThreshold = 2.0,
    estimator_timeout: o.EstimatorTimeout = 600.0,
    out_dir: OutDir = DEFAULT_OUT_DIR,
    workers: Workers = None,
    shard: Shard = None,
    full: Full = False,
    progress: Progress = True,
) -> None:
    """The options shared by eval and triage (their signature is reused, never called)."""


RUN_PARAMS = list(inspect.signature(_run_options, eval_str=True).parameters.values())
SELECTION_FLAGS = ("kitti_root", "sequence", "drive", "pair_kind", "step", "cams", "frames", "synthetic", "seeds",
                   "pairs", "images", "colmap", "matches", "gt_matches", "image_a", "image_b", "K", "K_a", "K_b", "T_ab", "F_gt")


@dataclass
class RunArgs:
    """The parsed shared options: a run configuration and how to execute it."""

    values: dict[str, Any]

    def __getattr__(self, name: str) -> Any:
        try:
            return self.values[name]
        except KeyError:
            raise AttributeError(name) from None

    @property
    def selects(self) -> bool:
        """Whether any selection flag was given (else a run in --out-dir is reused as configured)."""
        return any(self.values[k] not in (None, False) for k in SELECTION_FLAGS)

    def config(self, default_estimators: tuple[str, ...] = (), resume: bool = False):
        """The RunConfig of the flags, or, without selection flags, the run already in --out-dir (``-e`` replacing
        its estimators). Without ``-e``: the run's estimators, or fviz.api's default ones (``default_estimators``
        is kept for callers that pass them)."""
        return api.runs.run_config(self.out_dir, self.selection() if self.selects else None, resume=resume,
                                   **self.options())

    def options(self) -> dict[str, Any]:
        """The estimator and run options as :func:`fviz.api.evaluate_run` takes them."""
        keys = ("features", "max_keypoints", "ratio", "mutual", "threshold", "confidence", "max_iters", "seed", "norm",
                "eval_threshold", "estimator_timeout", "shard", "full")
        return {"estimators": tuple(self.estimator) if self.estimator else None, **{k: self.values[k] for k in keys}}

    def selection(self):
        """The selection flags, parsed, as :func:`fviz.api.select` takes them."""
        return api.select(
            self.kitti_root, sequence=self.sequence, drive=self.drive,
            kinds=tuple(split_list(self.pair_kind, "--pair")) or ("stereo",),
            steps=tuple(int_list(self.step, "--step")) or (1,), cams=o.parse_cams(self.cams),
            frames=parse_range(self.frames, "--frames", both=False), synthetic=self.synthetic,
            seeds=parse_range(self.seeds, "--seeds", both=True) if self.seeds else None,
            pairs=self.pairs, images=self.images, colmap=self.colmap, min_shared=self.min_shared, matches=self.matches,
            gt_matches=self.gt_matches, image_a=self.image_a, image_b=self.image_b, K=self.K, K_a=self.K_a, K_b=self.K_b,
            T_ab=self.T_ab, F_gt=self.F_gt)


def split_list(values: list[str] | None, flag: str) -> list[str]:
    """Repeated and comma-separated values, flattened."""
    out = [v.strip() for text in values or [] for v in text.split(",")]
    if any(not v for v in out):
        raise FvizError(f"{flag} {','.join(values)!r}: empty item")
    return out


def int_list(values: list[str] | None, flag: str) -> list[int]:
    items = split_list(values, flag)
    try:
        return [int(v) for v in items]
    except ValueError:
        raise FvizError(f"{flag} {','.join(items)!r}: expected integers") from None


def parse_range(text: str | None, flag: str, both: bool) -> tuple[int | None, int | None]:
    """``A:B`` -> (A, B), B exclusive; without ``both`` either side may be empty (None)."""
    if text is None:
        return (None, None)
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        a, b = (int(p) if p.strip() else None for p in parts)
    except ValueError:
        raise FvizError(f"{flag} {text!r}: expected START:END (integers, END exclusive)") from None
    if both and (a is None or b is None):
        raise FvizError(f"{flag} {text!r}: give both ends, A:B")
    if (a is not None and a < 0) or (b is not None and b < 0) or (a is not None and b is not None and a >= b):
        raise FvizError(f"{flag} {text!r}: need 0 <= START < END")
    return a, b


def run_command(fn: Callable[..., None]) -> Callable[..., None]:
    """A typer command taking the shared run options plus ``fn``'s own; ``fn(args: RunArgs, **own)``."""
    own = [p for p in inspect.signature(fn, eval_str=True).parameters.values() if p.name != "args"]
    names = {p.name for p in RUN_PARAMS}

    def command(**kwargs):
        args = RunArgs({k: kwargs.pop(k) for k in list(kwargs) if k in names})
        return fn(args, **kwargs)

    command.__signature__ = inspect.Signature(RUN_PARAMS + own)
    command.__name__, command.__doc__ = fn.__name__, fn.__doc__
    return command


def print_outcome(outcome, what: str = "eval") -> None:
    """One summary line and the report paths; on an interrupted run, how to finish it (exit 130)."""
    FEATURES_FILE = api.runs.FEATURES_FILE
    err = sys.stderr
    print(f"{what}: {outcome.total} pairs ({outcome.reused} already done, {outcome.computed} evaluated now, "
          f"{outcome.failed} not evaluated (pair errors), {outcome.detections} feature detections, {outcome.cached_features} images' "
          f"features read from the run's {FEATURES_FILE}) -> {outcome.out_dir}", file=err)
    for note, n in outcome.cache_notes.items():
        print(f"note: {outcome.out_dir}/{note}" + (f" ({n} times)" if n > 1 else ""), file=err)
    for path in outcome.paths.values():
        print(f"  {path}", file=err)
    missing = outcome.total - outcome.reused - outcome.computed
    if missing > 0 and not outcome.interrupted:
        print(f"{missing} pairs of the selection are not in {outcome.out_dir} yet: merge the missing shards, "
              f"or run fviz eval --out-dir {outcome.out_dir} --resume", file=err)
    if outcome.interrupted:
        print(f"interrupted: reports cover the finished pairs; finish with: fviz {what} --out-dir {outcome.out_dir} --resume",
              file=err)
        raise typer.Exit(130)


def print_failures(out_dir: Path) -> None:
    """The run's failures grouped by cause (summary.json's ``failures``), one line each, and a ground truth biased
    over the run (``gt_bias``), on stderr."""
    for line in api.Run(Path(out_dir), None).failure_lines():
        print(line, file=sys.stderr)


def print_figures(out_dir: Path) -> None:
    """The standard figures of summary.json as a table on stdout."""
    from rich.console import Console
    from rich.table import Table

    figures = api.Run(Path(out_dir), None).figures()
    if figures is None:
        return
    title, header, rows = figures
    t = Table(title=title)
    for c in header:
        t.add_column(c, justify="left" if c == "estimator" else "right")
    for row in rows:
        t.add_row(*row)
    Console(width=max(Console().width, 150)).print(t)


def eval_(args: RunArgs, resume: Resume = False) -> None:
    """Run estimators on every pair of a selection: metrics.csv/.parquet, summary.md and eval.rrd in --out-dir.

    Default estimators: inspect's (8point, ransac, magsac) plus `ahead`, straight-ahead motion from the cameras alone.
    Baselines: `-e ahead`, `-e mean:01,02` (the mean ground-truth F of other sequences, or `mean:A:B` of other
    synthetic seeds) and `-e oracle-mean` (the mean ground-truth F of the evaluated pairs: an oracle).

    Without selection flags, --resume continues the run in --out-dir as it was configured. Ctrl-C keeps the reports of the finished pairs (exit 130).
    """
    run = api.evaluate_run(args.selection() if args.selects else None, args.out_dir, workers=args.workers, resume=resume,
                           progress=args.progress, **args.options())
    print_figures(args.out_dir)
    print_outcome(run.outcome)
    print_failures(args.out_dir)


def merge(
    dirs: Annotated[list[Path], typer.Argument(help="Run folders (shards) to merge.")],
    out_dir: Annotated[Path, typer.Option("--out-dir", help="New run folder for the merged results.")],
) -> None:
    """Merge the run folders of `fviz eval --shard i/n` jobs into one run with all reports."""
    print_outcome(api.merge_runs(dirs, out_dir).outcome, "merge")


def register(app: typer.Typer) -> None:
    app.command("eval")(run_command(eval_))
    app.command("merge")(merge)
