"""Training from Python: :func:`train` runs a recipe (``fviz train`` is its client). Several GPUs: ``torchrun
--nproc_per_node N -m fviz train RECIPE`` (see :mod:`fviz.train.runtime`)."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

from fviz.api.names import python_errors
from fviz.errors import FvizError

if TYPE_CHECKING:  # pragma: no cover
    from fviz.train.loop import TrainResult

TRAIN_OUTPUTS = ("last.pt", "model.pt", "train.rrd", "heldout.json")


def __getattr__(name: str):
    """The training loop's names the command line prints with, imported on first use (torch)."""
    if name == "TrainingInterrupted":
        from fviz.train.loop import TrainingInterrupted

        return TrainingInterrupted
    if name in ("VALIDATION_FIGURES", "versus_constants"):
        from fviz.train import validation

        return getattr(validation, name)
    raise AttributeError(name)


def worker_error_line(message: str) -> str:
    """The message of an error raised in a DataLoader worker process, without the traceback torch wraps
    it in ("Caught FvizError in DataLoader worker process 0. Original Traceback ...")."""
    lines = [line for line in message.splitlines() if line.strip()]
    if len(lines) > 1 and "DataLoader worker" in lines[0]:
        last = lines[-1]
        return last.split("Error: ", 1)[1] if "Error: " in last else last
    return message


@python_errors
def train(recipe: str | os.PathLike, overrides: Sequence[str] = (), *, resume: bool = False, progress: bool = True,
          console: Any = None) -> TrainResult:
    """Train a fundamental-matrix network from a recipe (``fviz train``): last.pt, model.pt, train.rrd and
    heldout.json in the recipe's ``train.out_dir``.

    Args:
        recipe: a recipe TOML file (see recipes/).
        overrides: "KEY=VALUE" items replacing recipe keys, e.g. ("train.lr=3e-4", "model.variant=single-epi-abs").
        resume: continue from the last checkpoint in ``train.out_dir``.
        progress: the progress bar and the first line (rank 0 only).
        console: a ``rich.console.Console`` for them (default: stderr).

    Returns:
        The training's result: ``out_dir``, ``checkpoint``, ``weights``, ``recording``, ``step``, ``metrics``,
        ``seconds``. Ctrl-C or SIGTERM stops after the current step and raises
        ``TrainingInterrupted`` (an FvizError: ``step``, ``checkpoint``; continue with ``resume=True``).
    """
    from rich.console import Console

    from fviz.atomic import owning, target
    from fviz.lock import locked
    from fviz.run.execute import remove_leftovers
    from fviz.train.checkpoint import check_fresh, output_dir
    from fviz.train.loop import TrainingInterrupted
    from fviz.train.loop import train as run_training
    from fviz.train.recipe import load_recipe

    console = console or Console(stderr=True)
    config = load_recipe(Path(recipe), list(overrides))
    out_dir = output_dir(config)
    with owning(out_dir):  # a folder (or FIFO, or a link out of out_dir ...) where an output goes: refused now
        for name in TRAIN_OUTPUTS:
            target(out_dir / name)
    check_fresh(out_dir, resume)
    main = int(os.environ.get("RANK", "0")) == 0  # under torchrun only rank 0 talks
    if main and progress:
        console.print(f"training [bold]{config.model.variant}[/] at {config.input_hw[0]}x{config.input_hw[1]} "
                      f"on {config.data.source} -> {config.train.out_dir}  (Ctrl-C: stop, save, print the resume command)")
    try:
        # one training per out_dir (rank 0 holds it for all ranks): a second one is refused, naming the first
        with locked(out_dir, "train.out_dir") if main else contextlib.nullcontext():
            if main:
                remove_leftovers(out_dir, TRAIN_OUTPUTS)  # what a killed run left (the lock is ours)
            return run_training(config, resume=resume, progress=main and progress, console=console)
    except TrainingInterrupted:  # its step and checkpoint are the caller's
        raise
    except FvizError as exc:
        raise FvizError(worker_error_line(str(exc))) from None
