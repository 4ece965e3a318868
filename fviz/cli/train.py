"""``fviz train RECIPE [--set KEY=VALUE ...] [--resume]``: train one of the paper's networks.

Several GPUs: ``torchrun --nproc_per_node N -m fviz train RECIPE`` (see :mod:`fviz.train.runtime`).

The lead's CLI calls :func:`register` to add the command to its Typer app.  Errors are
:class:`fviz.errors.FvizError` (one line; the CLI prints it and exits 2).  Ctrl-C or SIGTERM
stops after the current step, saves a checkpoint, prints the ``--resume`` command and exits 130.
"""

from __future__ import annotations

import os
import shlex
from pathlib import Path

import typer


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

    from fviz.api import training

    console = Console(stderr=True)
    main = int(os.environ.get("RANK", "0")) == 0  # under torchrun only rank 0 talks
    try:
        result = training.train(recipe, list(set_), resume=resume, console=console)
    except training.TrainingInterrupted as exc:
        if main:
            console.print(f"interrupted ({exc.signal_name}) at step {exc.step}: saved {exc.checkpoint}", highlight=False)
            console.print(f"continue with: {resume_command(recipe, list(set_))}", highlight=False, soft_wrap=True)
        raise typer.Exit(exc.exit_code) from None
    if not main:
        return
    m = result.metrics
    summary = "  ".join(f"{k} {v:.4g}" for k, v in m.items() if k in training.VALIDATION_FIGURES)
    console.print(f"done: {result.step} steps in {result.seconds:.0f} s; held-out validation: {summary}")
    verdict = training.versus_constants(m)
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
