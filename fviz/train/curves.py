"""What a training run shows while it runs: its curves in ``train.rrd`` and its progress bar on the console.

``train.rrd`` (:class:`Curves`): a Rerun recording of the curves ``train/*`` and ``val/*`` on the ``step`` timeline,
each validation's verdict against the constants (``val/verdict``), and of the network on ``train.watch_pairs`` fixed
validation pairs every ``train.watch_every`` steps or at each checkpoint: its epipolar lines beside the ground
truth's and those of the constant validation sets it beside (the training pairs' mean F so far,
:class:`fviz.train.validation.TargetMean`: the same F in every pair's model-input pixels, as validation applies it),
through :func:`fviz.log_training_step` (a click in ``fviz open train.rrd --web`` draws a point's lines under each);
rewritten complete, footer included, under a temporary name and renamed into place at each checkpoint: after SIGKILL
it is the last checkpoint's complete recording.
``train/loss`` is the loss of each training batch in training mode (dropout on, BatchNorm on the batch's
statistics); ``val/loss`` the mean over the held-out validation pairs in eval mode (no dropout, BatchNorm's
running statistics, which lag behind the weights early in a run: a large gap in the first hundred steps is that,
not overfitting).

- :class:`Curves`: kept in memory, written at every checkpoint (:meth:`Curves.snapshot`), their series carried
  in ``last.pt`` (a resumed run rewrites them whole); :class:`NoCurves` when nothing is recorded;
  :func:`watched_pairs`: the validation pairs shown with the network's lines.
- :func:`progress_bar`: steps, loss and time left (rich), messages printed above it; a silent one when off.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import torch

from fviz.train.heldout import NO_BETTER

BASELINE = "mean F"  # the watched pairs' constant: the training pairs' mean F (validation's mean_f)


class Curves:
    """Training curves kept in memory and written as a *complete* Rerun .rrd at every checkpoint.

    Every snapshot writes all series so far to a temporary file (footer included) and renames it
    over ``path``: after SIGKILL the last snapshot is a valid recording, and nothing else (no
    ``.part``) is left behind.  The series travel in the checkpoint (:meth:`state`), so a resumed
    run rewrites the same ``train.rrd`` with the whole history.
    """

    def __init__(self, path: Path, recording_id: str, state: dict | None = None, watch: list | None = None,
                 notes: list | None = None):
        import rerun as rr

        self.rr = rr
        self.path = path
        self.recording_id = recording_id
        self.series: dict[str, tuple[list[int], list[float]]] = {
            k: (list(v[0]), list(v[1])) for k, v in (state or {}).items()
        }
        # the watched validation pairs (fviz.log_training_step): the pairs, and per frame the network's F on them and
        # the constant's (BASELINE; None before the first step; frames of an older fviz have none)
        self.pairs: list = []
        self.frames: list[tuple[int, list, list | None]] = [(int(f[0]), f[1], f[2] if len(f) > 2 else None) for f in (watch or [])]
        self.watch_seconds = 0.0  # spent on them: forward passes and logging
        # each validation's line setting the network beside the constants (versus_constants), a TextLog on VERDICT
        self.notes: list[tuple[int, str]] = [(int(s), str(t)) for s, t in (notes or [])]
        path.with_name(path.name + ".part").unlink(missing_ok=True)  # left by fviz versions that streamed into it

    def log(self, step: int, values: dict[str, float]) -> None:
        for key, value in values.items():
            if value is not None and math.isfinite(value):
                steps, vals = self.series.setdefault(key, ([], []))
                steps.append(int(step))
                vals.append(float(value))

    def state(self) -> dict[str, tuple[list[int], list[float]]]:
        return self.series

    def note(self, step: int, text: str) -> None:
        """Keep a validation's verdict line (one per step: the last counts)."""
        self.notes = [n for n in self.notes if n[0] != step] + [(int(step), text)]

    def watch(self, step: int, F_pred: torch.Tensor, F_constant: torch.Tensor | None = None) -> None:
        """Keep the network's F (B, 3, 3) on the watched pairs at ``step`` and the constant's (3, 3), the same for all
        (one frame; a step's last one counts)."""
        F = F_pred.detach().float().cpu().tolist()
        Fc = None if F_constant is None else F_constant.detach().double().cpu().tolist()
        self.frames = [f for f in self.frames if f[0] != step] + [(int(step), F, Fc)]

    def snapshot(self) -> None:
        """Make ``path`` a complete recording of everything logged so far (atomic rename)."""
        from fviz.record.layout import training_blueprint, training_style
        from fviz.record.writer import RecordingWriter

        rr = self.rr
        names = [str(i) for i in range(len(self.pairs))]
        bp = training_blueprint(names, [(p.size_a, p.size_b) for p in self.pairs], curves=True,
                                baseline=BASELINE if any(f[2] is not None for f in self.frames) else None)
        # through fviz's writer: a new file of its own (never a planted link), renamed over path only when
        # complete, and a full disk raises (Rerun's own file sink would stop with a log line and never return)
        with RecordingWriter(self.path, "fviz-train", blueprint=bp, recording_id=self.recording_id) as w:
            rec = w.rec
            for key, (steps, vals) in self.series.items():
                rec.log(key, rr.SeriesLines(**training_style(key)), static=True)
                rec.send_columns(key, indexes=[rr.TimeColumn("step", sequence=steps)], columns=rr.Scalars.columns(scalars=vals))
            if self.notes:
                from fviz.record.layout import TRAIN_TIMELINE, TRAIN_VERDICT

                for step, text in self.notes:
                    rec.set_time(TRAIN_TIMELINE, sequence=step)
                    rec.log(TRAIN_VERDICT, rr.TextLog(text, level="WARN" if text.startswith(NO_BETTER) else "INFO"))
            if self.pairs:
                from fviz.record.training import log_training_step

                t0 = time.perf_counter()
                for step, F, Fc in self.frames:
                    log_training_step(rec, step, self.pairs, F, names, blueprint=False, F_baseline=Fc, baseline_name=BASELINE)
                self.watch_seconds += time.perf_counter() - t0

    close = snapshot


class NoCurves:
    """The curves of a run that records nothing (``record=False``, or a rank other than 0)."""

    notes: list = []

    def log(self, *a, **k):
        pass

    snapshot = close = note = log

    def state(self) -> dict:
        return {}


def watched_pairs(val_ds, n: int, device: torch.device) -> tuple[list, tuple[torch.Tensor, torch.Tensor] | None]:
    """The first ``n`` validation pairs as :class:`fviz.Pair` (the model's input images, F in its pixels) and as
    the model's input batch (img_a, img_b (n, 1, H, W) on ``device``); ([], None) without them."""
    from fviz.data.arrays import pair_from_images

    n = min(n, len(val_ds) if val_ds is not None else 0)
    if n == 0:
        return [], None
    img_a, img_b, F_t = val_ds[list(range(n))]
    pairs = [pair_from_images(a[0].cpu().numpy(), b[0].cpu().numpy(), F_gt=F.cpu().numpy(), name=f"val{i}")
             for i, (a, b, F) in enumerate(zip(img_a, img_b, F_t))]
    return pairs, (img_a.to(device), img_b.to(device))


class NoBar:
    """The progress bar when it is off."""

    def advance(self) -> None:
        pass

    def show(self, loss: float) -> None:
        pass

    def print(self, text: str) -> None:
        pass

    def close(self) -> None:
        pass


class Bar:
    """A rich progress bar (steps, loss, time left); messages printed above it."""

    def __init__(self, total: int, start: int, name: str, console=None):
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.progress = Progress(
            TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("loss {task.fields[loss]}"),
            TimeElapsedColumn(), TimeRemainingColumn(), console=console,
        )
        self.task = self.progress.add_task(name, total=total, completed=start, loss="-")
        self.progress.start()

    def advance(self) -> None:
        self.progress.update(self.task, advance=1)

    def show(self, loss: float) -> None:
        self.progress.update(self.task, loss=f"{loss:.4g}")

    def print(self, text: str) -> None:
        self.progress.console.print(text)

    def close(self) -> None:
        self.progress.stop()


def progress_bar(enabled: bool, total: int, start: int, name: str, console=None):
    return Bar(total, start, name, console) if enabled else NoBar()
