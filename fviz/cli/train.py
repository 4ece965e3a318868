"""``fviz train RECIPE [--set KEY=VALUE ...] [--resume]``: train one of the paper's networks.

Several GPUs: ``torchrun --nproc_per_node N -m fviz train RECIPE`` (see :mod:`fviz.train.loop`).

The lead's CLI calls :func:`register` to add the command to its Typer app.  Errors are
:class:`fviz.errors.FvizError` (one line; the CLI prints it and exits 2).  Ctrl-C or SIGTERM
stops after the current step, saves a checkpoint, prints the ``--resume`` command and exits 130.
"""

from __future__ import annotations

import contextlib
import os
import shlex
from pathlib import Path

import typer

from fviz.errors import FvizError


TRAIN_OUTPUTS = ("last.pt", "model.pt", "train.rrd", "heldout.json")


def worker_error_line(message: str) -> str:
    """The message of an error raised in a DataLoader worker process, without the traceback torch wraps
    it in ("Caught FvizError in DataLoader worker process 0. Original Traceback ...")."""
    lines = [line for line in message.splitlines() if line.strip()]
    if len(lines) > 1 and "DataLoader worker" in lines[0]:
        last = lines[-1]
        return last.split("Error: ", 1)[1] if "Error: " in last else last
    return message


def resume_command(recipe: Path, overrides: list[str]) -> str:
    """The command line that continues this run."""
    args = ["fviz", "train", str(recipe)]
    for item in overrides:
        args += ["--set", item]
    return shlex.join([*args, "--resume"])


def train(
    recipe: Path = typer.Argument(..., help="Recipe TOML file (see recipes/)."),
    set_: list[str] = typer.Option([], "--set", help="Override a recipe key, e.g. --set train.lr=3e-4 --set model.variant=single-epi-abs (repeatable)."),
    resume: bool = typer.Option(False, "--resume", help="Continue from the last checkpoint in train.out_dir."),
) -> None:
    """Train a fundamental-matrix network from a recipe; writes last.pt, model.pt and train.rrd to train.out_dir."""
    from rich.console import Console

    from fviz.train.loop import TrainingInterrupted, check_fresh, output_dir
    from fviz.train.loop import train as run_training
    from fviz.train.recipe import load_recipe

    from fviz.atomic import owning, target
    from fviz.run.store import locked

    console = Console(stderr=True)
    config = load_recipe(recipe, list(set_))
    out_dir = output_dir(config)
    with owning(out_dir):  # a folder (or FIFO, or a link out of out_dir ...) where an output goes: refused now
        for name in TRAIN_OUTPUTS:
            target(out_dir / name)
    check_fresh(out_dir, resume)
    main = int(os.environ.get("RANK", "0")) == 0  # under torchrun only rank 0 talks
    if main:
        console.print(f"training [bold]{config.model.variant}[/] at {config.input_hw[0]}x{config.input_hw[1]} "
                      f"on {config.data.source} -> {config.train.out_dir}  (Ctrl-C: stop, save, print the resume command)")
    try:
        # one training per out_dir (rank 0 holds it for all ranks): a second one is refused, naming the first
        with locked(out_dir, "train.out_dir") if main else contextlib.nullcontext():
            if main:
                from fviz.run.execute import remove_leftovers

                remove_leftovers(out_dir, TRAIN_OUTPUTS)  # what a killed run left (the lock is ours)
            result = run_training(config, resume=resume, progress=main, console=console)
    except TrainingInterrupted as exc:
        if main:
            console.print(f"interrupted ({exc.signal_name}) at step {exc.step}: saved {exc.checkpoint}", highlight=False)
            console.print(f"continue with: {resume_command(recipe, list(set_))}", highlight=False, soft_wrap=True)
        raise typer.Exit(exc.exit_code) from None
    except FvizError as exc:
        raise FvizError(worker_error_line(str(exc))) from None
    if not main:
        return
    from fviz.train.loop import VALIDATION_FIGURES, versus_constants

    m = result.metrics
    summary = "  ".join(f"{k} {v:.4g}" for k, v in m.items() if k in VALIDATION_FIGURES)
    console.print(f"done: {result.step} steps in {result.seconds:.0f} s; held-out validation: {summary}")
    verdict = versus_constants(m)
    if verdict:
        console.print(verdict, highlight=False, soft_wrap=True)
    console.print(f"checkpoint {result.checkpoint}\nweights    {result.weights}\ncurves     {result.recording}")
    report = result.out_dir / "heldout.json"
    if report.is_file():
        import json

        figures = json.loads(report.read_text())
        for name in [n for n in ("model", "constant", "mean_f") if n in figures]:
            f = figures[name]
            auc = "/".join(f"{v:.3g}" for v in f.get("pose_auc", {}).values())
            console.print(f"held-out {', '.join(figures['sequences'])}, {name:8s}: pose AUC@5/10/20 {auc}, "
                          f"temporal median SED {f['temporal_sed_median']:.3g} px, "
                          f"rotation error {f['temporal_rot_err_median']:.3g} deg, yaw correlation {f['temporal_yaw_corr']:.3g}, "
                          f"stereo epipole error {f['stereo_epipole_err_median']:.3g} deg", highlight=False)
        for other, tests in figures.get("paired", {}).items():
            t = tests.get("pose_err_deg", {})
            console.print(f"held-out    model vs {other}, pose error: {t.get('wins')} wins, {t.get('losses')} losses, "
                          f"{t.get('ties')} ties, Wilcoxon p {t.get('wilcoxon_p', float('nan')):.3g}: {t.get('verdict')}",
                          highlight=False)
        if figures.get("verdict"):
            console.print(f"held-out    {figures['verdict']}", highlight=False, soft_wrap=True)
        console.print(f"held-out    {report}")


def register(app: typer.Typer) -> None:
    """Add the ``train`` command to ``app``."""
    app.command("train")(train)
