"""The training loop: ``train(recipe) -> TrainResult``.

Its parts: the losses (:mod:`fviz.train.losses`); validation and the two constants set beside the network
(:mod:`fviz.train.validation`); the curves in ``train.rrd`` and the progress bar (:mod:`fviz.train.curves`); the
device, processes, loaders, batches and signals (:mod:`fviz.train.runtime`); checkpoints and the state a run
resumes from (:mod:`fviz.train.checkpoint`); the data (:mod:`fviz.train.data`, :mod:`fviz.train.splits`).

Optimizer: Adam (``lr``, ``weight_decay``), gradient norm clipped at ``grad_clip`` (1.0); the
learning rate is constant or follows a cosine to 0 at the last step (``schedule``), after
``warmup_steps`` of linear warm-up (computed from the step count, so resuming keeps it).

Validation every epoch, or every ``val_every`` steps (:func:`fviz.train.validation.validate`).

Outputs in ``train.out_dir``: ``last.pt`` (full checkpoint: model, optimizer, recipe, metrics, step,
code version, the curves; rewritten atomically every ``checkpoint_every`` steps and at each
validation), ``model.pt`` (weights only, ``export_dtype``, written at the end: the file to ship), and
``train.rrd`` (the curves and the network on a few watched validation pairs, :mod:`fviz.train.curves`; rewritten
complete at each checkpoint).  Resuming (``resume=True``, CLI ``--resume``) continues
from ``last.pt`` with its step count, optimizer state, position in the epoch and curves, and
rewrites ``train.rrd`` with the whole history.  A fresh run refuses an ``out_dir`` that already
holds ``last.pt``; ``train.init`` starts a fresh run from another model's weights (fine-tuning).

Ctrl-C or SIGTERM (single process): the loop finishes the current step, writes ``last.pt`` and
``train.rrd``, and raises :class:`TrainingInterrupted` (the CLI prints the ``--resume`` command and
exits 130); a second signal stops at once with the previous checkpoint.  DataLoader workers ignore
SIGINT (the main process decides).

A non-finite loss stops training with :class:`TrainingDiverged` (an FvizError) naming the step;
``last.pt`` is then the last good checkpoint.  Losses stay on the device and are brought to the host
every ``log_every`` steps and before every validation and checkpoint (one sync, so that on a GPU the
next batch renders while the current step runs); that is where a NaN is found, and no weights are
saved between a NaN step and its discovery.

Device, data loading and several GPUs (torchrun): :mod:`fviz.train.runtime`.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from fviz.errors import FvizError
from fviz.train.checkpoint import (
    RunState,
    atomic_save,
    check_fresh,
    code_version,
    export_weights,
    load_into,
    make_checkpoint,
    make_out_dir,
    output_dir,
    read_checkpoint,
    resume_state,
)
from fviz.train.curves import Curves, NoCurves, progress_bar, watched_pairs
from fviz.train.losses import f_loss, sample_points_on_geometry, sed_loss
from fviz.train.recipe import Recipe, load_recipe, resolve_path
from fviz.train.runtime import (
    Batches,
    StopRequests,
    autocast_dtype,
    barrier,
    dist_setup,
    epoch_batches,
    loader,
    total_steps,
    training_sets,
)
from fviz.train.validation import VALIDATION_FIGURES, TargetMean, validate, versus_constants


class TrainingInterrupted(FvizError):
    """Ctrl-C or SIGTERM stopped training after a complete step; ``checkpoint`` holds that step."""

    exit_code = 130

    def __init__(self, message: str, step: int, checkpoint: Path | None, signal_name: str):
        super().__init__(message)
        self.step = step
        self.checkpoint = checkpoint
        self.signal_name = signal_name


class TrainingDiverged(FvizError):
    """The loss became NaN or infinite; ``checkpoint`` is the last good one (or None)."""

    def __init__(self, message: str, step: int, checkpoint: Path | None):
        super().__init__(message)
        self.step = step
        self.checkpoint = checkpoint


@dataclass
class TrainResult:
    out_dir: Path
    checkpoint: Path
    weights: Path | None
    recording: Path | None
    step: int
    epoch: int
    metrics: dict[str, float]  # the last validation
    history: list[dict[str, Any]]  # every validation: {"step", "epoch", metrics...}
    losses: list[float] = field(default_factory=list)  # training loss of every step of this run
    seconds: float = 0.0
    # where the time went (benchmarks/bench_train_record.py): the optimizer steps (batch on the device, forward,
    # backward, update) and the watched pairs (their forward passes and their logging into train.rrd)
    step_seconds: float = 0.0
    watch_seconds: float = 0.0


def train(
    recipe: Recipe | str | Path,
    *,
    resume: bool = False,
    progress: bool = False,
    datasets: tuple[Any, Any] | None = None,
    record: bool = True,
    console: Any = None,
    held_out: bool = True,
) -> TrainResult:
    """Train the recipe's model (see the module docstring).  Returns a :class:`TrainResult`.

    ``datasets`` = (train, val) replaces the recipe's data source (tests, benchmarks); they must
    follow the batch protocol of :mod:`fviz.train.data`.  ``record=False`` skips the .rrd.
    ``held_out``: at the end, the eval's figures of ``model.pt`` on ``data.val_sequences``
    (:func:`fviz.train.heldout.heldout_report`) go to ``out_dir/heldout.json``.
    Raises FvizError for bad input and :class:`TrainingDiverged` when the loss becomes NaN.
    """
    from fviz.models.model import FNet
    from fviz.train.splits import network_config

    t_start = time.perf_counter()
    if not isinstance(recipe, Recipe):
        recipe = load_recipe(recipe)
    t = recipe.train
    rank, world, device = dist_setup(t.device)
    main = rank == 0
    out_dir = output_dir(recipe)
    if main:
        make_out_dir(out_dir)
    check_fresh(out_dir, resume)

    if t.threads:
        torch.set_num_threads(t.threads)
    torch.manual_seed(t.seed + rank)
    model = FNet.from_config(network_config(recipe)).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=t.lr, weight_decay=t.weight_decay)
    amp_dtype = autocast_dtype(t.amp, device)
    scaler = torch.amp.GradScaler("cuda", enabled=amp_dtype == torch.float16)
    if t.init and not resume:
        load_into(model, read_checkpoint(resolve_path(t.init)), what=f"train.init {t.init}")
    state = resume_state(out_dir / "last.pt", model, opt, scaler, world) if resume else RunState()

    datasets, loader_workers = training_sets(recipe, datasets, device, progress and main, console)
    total = total_steps(t, len(datasets[0]), rank, world)
    if not resume and t.t_norm_weight > 0:
        unit_translation(model, datasets[0], t.batch_size, device)

    run = _Run(recipe, model, opt, scaler, amp_dtype, device, rank, world, out_dir, state, datasets, loader_workers,
               total, resume=resume, record=record, progress=progress, console=console)
    stop = StopRequests(main and world == 1).__enter__()
    completed = False  # an error in flight is not hidden by one of closing train.rrd after it
    try:
        run.start()
        while not run.done:
            run.run_epoch(stop)
        weights = run.finish(held_out)
        completed = True
    finally:
        stop.__exit__()
        run.close(completed)
    return run.result(weights, t_start)


class _Run:
    """One training run: the model and its optimizer, the data, the curves, where the run stands (:class:`RunState`)
    and its steps, validations and checkpoints (rank 0 alone validates, logs and writes)."""

    def __init__(self, recipe: Recipe, model, opt, scaler, amp_dtype: torch.dtype | None, device: torch.device,
                 rank: int, world: int, out_dir: Path, state: RunState, datasets: tuple, loader_workers: int, total: int,
                 *, resume: bool, record: bool, progress: bool, console: Any):
        t = self.t = recipe.train
        self.recipe, self.model, self.opt, self.scaler, self.amp_dtype = recipe, model, opt, scaler, amp_dtype
        self.device, self.rank, self.world, self.main = device, rank, world, rank == 0
        self.out_dir, self.ckpt_path, self.state, self.total = out_dir, out_dir / "last.pt", state, total
        self.norm = recipe.model.variant.rsplit("-", 1)[1]
        self.train_ds, self.val_ds = datasets
        self.net = model
        if world > 1:
            self.net = torch.nn.parallel.DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None)

        pin = device.type == "cuda" and loader_workers > 0
        self.train_sampler = Batches()
        self.train_loader = loader(self.train_ds, self.train_sampler, loader_workers, pin)
        self.val_loader = None
        if self.main and self.val_ds is not None and len(self.val_ds):
            val_batches = Batches(epoch_batches(len(self.val_ds), t.batch_size, 0, 0, shuffle=False))
            self.val_loader = loader(self.val_ds, val_batches, loader_workers, pin)
        self.curves, self.watch_batch = self._curves(record)

        self.version = code_version() if self.main else None
        self.last_good = (self.ckpt_path if self.ckpt_path.exists() else None, state.step if resume else None)  # (path, step)
        self.losses: list[float] = []
        self.last_checkpoint = state.step if resume else -1
        history = state.history
        self.metrics: dict[str, float] = {k: v for k, v in history[-1].items() if k not in ("step", "epoch")} if history else {}
        self.step_seconds = 0.0
        self.pending: list[torch.Tensor] = []  # losses of the steps since the last flush, still on the device
        self.point_rng = torch.Generator().manual_seed(t.seed * 7919 + state.step + rank)  # virtual correspondences of sed_loss
        self.best = min((h[t.keep_best] for h in history if t.keep_best in h), default=math.inf) if t.keep_best else math.inf
        self.last_grad: Any = None
        # the constant F of the training pairs stepped on (validation's mean_f), signs aligned with the first pair's
        self.target_mean = TargetMean(state.target_mean, ref=None if state.target_mean else self.train_ds[[0]][2][0])
        self.progress = progress
        self.bar = progress_bar(progress and self.main, total, state.step, recipe.model.variant, console)
        self.done = state.step >= total
        self.last_validated = history[-1]["step"] if history else -1

    def _curves(self, record: bool) -> tuple[Any, tuple[torch.Tensor, torch.Tensor] | None]:
        """The curves of train.rrd (rank 0, ``record``) and the watched pairs' input batch (or None)."""
        if not (self.main and record):
            return NoCurves(), None
        s = self.state
        curves = Curves(self.out_dir / "train.rrd", s.recording_id, s.curves, s.watch, s.notes)
        t0 = time.perf_counter()
        curves.pairs, watch_batch = watched_pairs(self.val_ds, self.t.watch_pairs, self.device)
        curves.watch_seconds += time.perf_counter() - t0
        return curves, watch_batch

    def _autocast(self):
        return torch.autocast(self.device.type, dtype=self.amp_dtype or torch.float32, enabled=self.amp_dtype is not None)

    def start(self) -> None:
        """Watch where the network starts (unless the resumed recording holds this step)."""
        if self.watch_batch is not None and not any(f[0] == self.state.step for f in self.curves.frames):
            self.watch()

    def run_epoch(self, stop: StopRequests) -> None:
        """The rest of the current epoch, up to the last step or a stop request; at its end validation (unless
        ``val_every``) and a checkpoint.  Raises :class:`TrainingInterrupted` after a stop request's checkpoint."""
        s, t = self.state, self.t
        batches = epoch_batches(len(self.train_ds), t.batch_size, t.seed, s.epoch, self.rank, self.world)
        self.train_sampler.batches = batches[s.batch_in_epoch:]
        self.net.train()
        for img_a, img_b, F_t in self.train_loader:
            self.step_on(img_a, img_b, F_t)
            self.after_step()
            if s.step >= self.total:
                self.done = True
                break
            if stop.received:
                break
        self.flush()
        if stop.received:
            if self.last_checkpoint != s.step:
                self.checkpoint()
            raise TrainingInterrupted(
                f"{stop.received} at step {s.step} of {self.total}: checkpoint {self.ckpt_path} holds it", s.step,
                self.ckpt_path, stop.received,
            )
        if s.batch_in_epoch >= len(batches):  # the epoch is complete
            s.epoch += 1
            s.batch_in_epoch = 0
            if not t.val_every:
                self.run_validation()
            self.checkpoint()
            self.done = self.done or s.epoch >= t.epochs

    def loss(self, F_pred: torch.Tensor, F_t: torch.Tensor) -> torch.Tensor:
        """The training loss of a batch: :func:`f_loss`, and the translation-length and SED terms when weighted."""
        t, hw, head = self.t, self.recipe.input_hw, self.model.head
        loss = f_loss(F_pred, F_t, self.norm, t.l1_weight, t.l2_weight, t.loss_frame, hw)
        if t.t_norm_weight > 0 and getattr(head, "t_raw_norm", None) is not None:
            loss = loss + t.t_norm_weight * head.t_raw_norm.log().square().mean()
        if t.sed_weight > 0:
            xa, xb = sample_points_on_geometry(F_t, hw, t.sed_points, self.point_rng)
            loss = loss + t.sed_weight * sed_loss(F_pred, xa, xb)
        return loss

    def step_on(self, img_a: torch.Tensor, img_b: torch.Tensor, F_t: torch.Tensor) -> None:
        """One optimizer step on a batch; its loss stays on the device until the next :meth:`flush`."""
        s, t, opt, scaler = self.state, self.t, self.opt, self.scaler
        t_step = time.perf_counter()
        img_a = img_a.to(self.device, non_blocking=True)
        img_b = img_b.to(self.device, non_blocking=True)
        F_t = F_t.to(self.device, non_blocking=True)
        self.target_mean.add(F_t)
        with self._autocast():
            F_pred = self.net(img_a, img_b)
        loss = self.loss(F_pred, F_t)
        self.pending.append(loss.detach())  # checked at the next flush (no host sync per step)
        for group in opt.param_groups:
            group["lr"] = lr_at(s.step, self.total, t)
        opt.zero_grad(set_to_none=True)
        scaler.scale(loss).backward()
        if t.grad_clip > 0:
            scaler.unscale_(opt)
            self.last_grad = torch.nn.utils.clip_grad_norm_(self.model.parameters(), t.grad_clip)
        scaler.step(opt)
        scaler.update()
        self.step_seconds += time.perf_counter() - t_step  # the host's view: on a GPU, kernels may still run
        s.step += 1
        s.batch_in_epoch += 1
        self.bar.advance()

    def after_step(self) -> None:
        """What a step's count calls for: logging, watching, validating, checkpointing."""
        step, t = self.state.step, self.t
        if step % t.log_every == 0 or step == 1:
            self.flush()
        if self.watch_batch is not None and t.watch_every and step % t.watch_every == 0:
            self.watch()
        if t.val_every and step % t.val_every == 0:
            self.run_validation()
            self.checkpoint()
        elif t.checkpoint_every and step % t.checkpoint_every == 0:
            self.checkpoint()

    def flush(self) -> None:
        """Bring the pending losses to the host (one sync), stop on a non-finite one, log them."""
        if not self.pending:
            return
        s, t = self.state, self.t
        vals = torch.stack(self.pending).float()
        if self.world > 1:
            import torch.distributed as dist

            dist.all_reduce(vals)  # a NaN on any rank makes the mean NaN on all: all stop together
            vals = vals / self.world
        host = vals.tolist()
        first = s.step - len(host) + 1
        self.pending.clear()
        for i, value in enumerate(host):
            if not math.isfinite(value):
                path, good_step = self.last_good
                where = (f"the last good checkpoint is {path} (step {good_step})"
                         if path is not None else "no checkpoint had been written yet")
                raise TrainingDiverged(
                    f"training stopped: the loss became {value} at step {first + i} (epoch {s.epoch + 1}); {where}. "
                    "Lower train.lr or check the data", first + i, path,
                )
        self.losses.extend(host)
        for i, value in enumerate(host):
            if (first + i) % t.log_every == 0 or first + i == 1:
                self.curves.log(first + i, {"train/loss": value})
        grad = float(self.last_grad) if self.last_grad is not None else None
        self.curves.log(s.step, {"train/grad_norm": grad, "train/lr": self.opt.param_groups[0]["lr"]})
        self.bar.show(host[-1])

    def checkpoint(self) -> None:
        """Write last.pt and train.rrd (rank 0), then wait for every rank."""
        s = self.state
        self.flush()
        if self.main:
            ckpt = make_checkpoint(
                self.model, optimizer=self.opt, scaler=self.scaler, recipe=self.recipe.to_dict(),
                metrics={"last": self.metrics, "history": s.history}, step=s.step, epoch=s.epoch,
                batch_in_epoch=s.batch_in_epoch, recording_id=s.recording_id, version=self.version,
            )
            ckpt.update(curves=self.curves.state(), notes=self.curves.notes, target_mean=self.target_mean.state())
            if self.watch_batch is not None:
                if not self.t.watch_every:
                    self.watch()
                ckpt["watch"] = self.curves.frames
            atomic_save(ckpt, self.ckpt_path)
            self.last_good = (self.ckpt_path, s.step)
            self.curves.snapshot()
        self.last_checkpoint = s.step
        barrier(self.world)

    def watch(self) -> None:
        """The network's F on the watched pairs at this step, for train.rrd (eval mode, as validation)."""
        t0 = time.perf_counter()
        was_training = self.model.training
        self.model.eval()
        with torch.no_grad(), self._autocast():
            F_pred = self.model(*self.watch_batch, strict_norm=False)
        self.model.train(was_training)
        self.curves.watch(self.state.step, F_pred, self.target_mean.F())  # beside validation's constant (mean_f)
        self.curves.watch_seconds += time.perf_counter() - t0

    def run_validation(self) -> None:
        """Validate (rank 0): the metrics into the curves and the history, the verdict against the constants,
        best.pt when ``keep_best`` improves, a line above the progress bar."""
        s, t = self.state, self.t
        self.last_validated = s.step
        self.flush()
        if not (self.main and self.val_loader is not None):
            return
        self.metrics = metrics = validate(self.model, self.val_loader, self.recipe, self.device, self.amp_dtype,
                                          mean_f=self.target_mean.F())
        s.history.append({"step": s.step, "epoch": s.epoch, **metrics})
        self.curves.log(s.step, {f"val/{k}": v for k, v in metrics.items()})
        verdict = versus_constants(metrics)
        if verdict:
            self.curves.note(s.step, verdict)
        if t.keep_best and metrics.get(t.keep_best, math.inf) < self.best:
            self.best = metrics[t.keep_best]
            dtype = torch.float16 if t.export_dtype == "float16" else torch.float32
            atomic_save(make_checkpoint(self.model, recipe=self.recipe.to_dict(), metrics={"last": metrics, "history": s.history},
                                        step=s.step, epoch=s.epoch, recording_id=s.recording_id, dtype=dtype, version=self.version),
                        self.out_dir / "best.pt")
        if self.progress:
            self.bar.print(self._validation_line(metrics))
            if verdict:
                self.bar.print(f"step {s.step}: {verdict}")

    def _validation_line(self, metrics: dict[str, float]) -> str:
        s, recent = self.state, self.losses[-self.t.log_every:]
        train_part = (f"train loss {sum(recent) / len(recent):.4g} (mean of the last {len(recent)} batches, "
                      "training mode)") if recent else ""
        others = "  ".join(f"{k} {v:.4g}" for k, v in metrics.items() if k in VALIDATION_FIGURES and k != "loss")
        return (f"step {s.step} (epoch {s.epoch}): {train_part} | val loss {metrics.get('loss', float('nan')):.4g} "
                f"({len(self.val_ds)} held-out pairs, eval mode: BatchNorm running statistics, no dropout) | {others}")

    def finish(self, held_out: bool) -> Path | None:
        """The last validation and checkpoint, model.pt and heldout.json (rank 0); -> model.pt (None on other ranks)."""
        step = self.state.step
        self.flush()
        if self.last_validated != step:
            self.run_validation()
        if self.last_checkpoint != step:
            self.checkpoint()
        if not self.main:
            return None
        weights = export_weights(self.ckpt_path, self.out_dir / "model.pt", self.t.export_dtype)
        if held_out:
            from fviz.atomic import write_text
            from fviz.train.heldout import heldout_report

            report = heldout_report(self.recipe, weights)
            if report:
                write_text(self.out_dir / "heldout.json", json.dumps(report, indent=1))
        return weights

    def close(self, completed: bool) -> None:
        """Stop the bar, write train.rrd a last time, leave the process group."""
        self.bar.close()
        if self.main:
            try:
                self.curves.close()
            except FvizError:  # a full disk (one line naming train.rrd); an error in flight goes first
                if completed:
                    raise
        if self.world > 1:
            import torch.distributed as dist

            dist.destroy_process_group()

    def result(self, weights: Path | None, t_start: float) -> TrainResult:
        s = self.state
        return TrainResult(
            out_dir=self.out_dir, checkpoint=self.ckpt_path, weights=weights, recording=getattr(self.curves, "path", None),
            step=s.step, epoch=s.epoch, metrics=self.metrics, history=s.history, losses=self.losses,
            seconds=time.perf_counter() - t_start, step_seconds=self.step_seconds,
            watch_seconds=getattr(self.curves, "watch_seconds", 0.0),
        )


def unit_translation(model, train_ds, batch_size: int, device: torch.device) -> float | None:
    """REC heads: rescale the translation outputs so that their median raw length on the first training
    batch is 1 (the same F, a translation that turns as fast as the angles; see fviz/models/heads.py).
    Returns the factor (None for other heads)."""
    if not hasattr(model.head, "unit_translation_"):
        return None
    img_a, img_b, _ = train_ds[list(range(min(len(train_ds), max(batch_size, 16))))]
    was_training = model.training
    model.eval()
    with torch.no_grad():
        features = model.features(img_a.to(device), img_b.to(device))
    model.train(was_training)
    return model.head.unit_translation_(features)


def lr_at(step: int, total: int, t) -> float:
    """Learning rate of the step after ``step`` completed ones: linear warm-up, then constant or cosine to 0."""
    if t.warmup_steps and step < t.warmup_steps:
        return t.lr * (step + 1) / t.warmup_steps
    if t.schedule == "cosine":
        span = max(total - t.warmup_steps, 1)
        progress = min(max((step - t.warmup_steps) / span, 0.0), 1.0)
        return t.lr * 0.5 * (1.0 + math.cos(math.pi * progress))
    return t.lr
