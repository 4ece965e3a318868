"""``fviz triage``: rank a run's pairs worst first with tagged failure causes; ``fviz compare``: two estimators
pair by pair. Triage takes eval's options (:func:`fviz.cli.eval.run_command`) and evaluates only what the
run in --out-dir lacks."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from fviz import api
from fviz.cli import options as o
from fviz.cli.eval import DEFAULT_OUT_DIR, RunArgs, print_outcome, run_command
from fviz.errors import FvizError

By = Annotated[Optional[str], typer.Option("--by", help="Estimator whose metric ranks the pairs (default: the first estimator named).")]
Metric = Annotated[str, typer.Option("--metric", help="Metric to rank by (worst first), e.g. sed_median, pose_err_deg, nsgd, inlier_ratio.")]
Top = Annotated[int, typer.Option("--top", help="Pairs listed in triage.md and recorded in triage.rrd.")]
RunDir = Annotated[Optional[Path], typer.Argument(metavar="RUN", help="The run folder (the same as --out-dir RUN; as in `fviz table RUN`).",
                                                  show_default=False)]


def one_run_folder(positional: Path | None, out_dir: Path | None, default: Path | None = None) -> Path | None:
    """The run folder given as RUN or as --out-dir RUN (either way, as every command takes it); both must agree.
    A file, or a recording's name (``*.rrd``), is a one-line error: a run is a folder."""
    for given, flag in ((positional, ""), (out_dir, "--out-dir ")):
        if given is not None and (Path(given).is_file() or (Path(given).suffix == ".rrd" and not Path(given).is_dir())):
            what = "a recording" if Path(given).suffix == ".rrd" else "a file"
            raise FvizError(f"{flag}{given}: {what}, not a run folder: give the folder an fviz eval run wrote (its "
                            f"--out-dir)" + (f"; open a recording with fviz open {given}" if Path(given).suffix == ".rrd" else ""))
    if positional is None:
        return out_dir
    if out_dir is not None and out_dir != default and Path(out_dir).absolute() != Path(positional).absolute():
        raise FvizError(f"{positional} and --out-dir {out_dir}: two run folders; give the run once (RUN or --out-dir RUN)")
    return positional


def triage(args: RunArgs, run: RunDir = None, by: By = None, metric: Metric = "sed_median", top: Top = 20) -> None:
    """Findings per estimator (ignores-input, worse-than-baseline), then pairs ranked by a metric of one estimator,
    worst first, with likely causes; writes triage.md and triage.rrd.

    Runs eval first with resume semantics: a finished run in --out-dir is reused (its estimators kept, only missing
    pairs or estimators computed). Without selection flags, the run in --out-dir is triaged as it was configured.
    """
    from fviz.cli.eval import print_failures, print_figures

    args.values["out_dir"] = one_run_folder(run, args.out_dir, DEFAULT_OUT_DIR)
    result = api.triage_run(args.out_dir, args.selection() if args.selects else None, by=by, metric=metric, top=top,
                            workers=args.workers, progress=args.progress, **args.options())
    print_figures(args.out_dir)
    print_outcome(result.eval, "triage")
    _print_findings(result)
    _print_ranking(result, metric, top)
    print_failures(args.out_dir)


def _print_findings(result) -> None:
    for f in result.findings:
        for tag, why in f.flags:
            print(f"{f.name}: {tag}: {why}")


def _print_ranking(result, metric: str, top: int) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"worst {min(top, len(result.ranked))} of {len(result.ranked)} pairs by {metric} of {result.by}")
    for c in ("rank", "pair", metric, "tags"):
        t.add_column(c, justify="right" if c in ("rank", metric) else "left")
    for r in result.ranked[:top]:
        t.add_row(str(r.rank), r.key, "error" if r.failed else f"{r.value:.4g}", ", ".join(x for x, _ in r.tags))
    console = Console(width=max(Console().width, 140))
    console.print(t)
    console.print(f"{result.markdown}\n{result.recording}")
    if result.ranked:  # each listed pair's own command is in triage.md
        import shlex

        command = shlex.join(["fviz", "open", str(result.markdown.parent), "--pair", result.ranked[0].key, "--web"])
        console.print(f"a pair from the run (images, matches, lines; click, edit): {command}", markup=False, soft_wrap=True)


def compare(
    run: RunDir = None,
    a: Annotated[Optional[str], typer.Option("--a", help="Estimator a (with --out-dir).")] = None,
    b: Annotated[Optional[str], typer.Option("--b", help="Estimator b (with --out-dir).")] = None,
    out_dir: Annotated[Optional[Path], typer.Option("--out-dir", help="Run folder holding both estimators; compare.md goes here.")] = None,
    run_a: Annotated[Optional[Path], typer.Option("--run-a", help="Run folder a (with --run-b and --estimator).")] = None,
    run_b: Annotated[Optional[Path], typer.Option("--run-b", help="Run folder b.")] = None,
    estimator: Annotated[Optional[str], typer.Option("--estimator", "-e", help="The estimator compared across --run-a / --run-b.")] = None,
    metric: Annotated[str, typer.Option("--metric", help="Metric compared pair by pair, e.g. sed_median, pose_err_deg, nsgd, inlier_ratio.")] = "sed_median",
    fail_threshold: Annotated[Optional[float], typer.Option(
        "--fail-threshold", help="A metric worse than this fails the pair (default: the metric's own threshold: "
        "sed/sampson > 2 px, pose/rotation/translation/epipole errors > 10 deg, nsgd > 0.05, inlier ratios < 0.5).",
        callback=o.checked("--fail-threshold", lambda v: v is None or math.isfinite(v), "must be a number"))] = None,
    tie: Annotated[float, typer.Option("--tie", help="Differences up to this (in the metric's unit) are ties.",
                                       callback=o.checked("--tie", lambda v: math.isfinite(v) and v >= 0, "must be a number >= 0"))] = 0.0,
    tie_rel: Annotated[float, typer.Option("--tie-rel", help="Differences up to this fraction of the larger value are ties (0: none).",
                                           callback=o.checked("--tie-rel", lambda v: 0 <= v < 1, "must be in [0, 1)"))] = 0.05,
    out: Annotated[Optional[Path], typer.Option("--out", help="Markdown file to write (default: compare.md in --out-dir, else in --run-a).")] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing file that holds another comparison.")] = False,
) -> None:
    """Wins, losses and ties of estimator a against b pair by pair, Wilcoxon's signed-rank test of the differences,
    the pairs where only one of them fails (where they sit in the run, the command reopening each), and every
    pair's difference (compare.md); compare.rrd beside it plots both per pair."""
    out_dir = one_run_folder(run, out_dir)
    if run_a or run_b:
        if not (run_a and run_b and estimator) or a or b:
            raise FvizError("compare: give --run-a D1 --run-b D2 --estimator NAME, or --out-dir D --a NAME --b NAME")
        runs, names, dest = (run_a, run_b), estimator, out_dir or run_a
    else:
        if not (out_dir and a and b):
            raise FvizError("compare: give --out-dir D --a NAME --b NAME, or --run-a D1 --run-b D2 --estimator NAME")
        runs, names, dest = (out_dir, None), (a, b), out_dir
    path = out or Path(dest) / api.runs.COMPARE_FILE
    o.check_out_dir(path.parent, "--out" if out else "--out-dir")
    c = api.compare_runs(*runs, estimators=names, metric=metric, fail_threshold=fail_threshold, tie=tie, tie_rel=tie_rel,
                         out=path, force=force)
    _print_comparison(c)


def _print_comparison(c) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"{c.a.label} vs {c.b.label}: {c.metric}")
    t.add_column("")
    t.add_column("value", justify="right")
    for what, n in c.rows():
        t.add_row(what, n)
    Console().print(t)
    print(f"{c.markdown} (replaced the previous version)" if c.replaced else c.markdown, file=sys.stderr)
    print(f"{c.recording} (the per-pair plot: fviz open {c.recording})", file=sys.stderr)


def register(app: typer.Typer) -> None:
    app.command("triage")(run_command(triage))
    app.command("compare")(compare)
