"""The training loop: ``train(recipe) -> TrainResult``.

Loss (paper, Sec. 4): L1 + L2 between the predicted and the target F, both normalized by the
model's layer, per pair ``l1_weight * mean|F - F_t| + l2_weight * mean (F - F_t)^2``.  F is only
defined up to sign: for fbn and abs the loss of a pair is the smaller of the losses of F and -F
(ETR fixes the sign itself).  ``loss_frame = "conditioned"`` (the default) compares the matrices
after mapping both to coordinates where the image spans [-1, 1] along its long side
(:func:`fviz.models.heads.conditioning_matrix`) and normalizing them again; ``"pixel"`` compares
them in model-input pixels, the literal reading of the paper.  Measured on synthetic scenes (48 x 160,
Siamese REC+POS FBN, 1500 steps of batch 16, lr 1e-3): the pixel-frame loss never left its starting
plateau (validation loss 0.357, f_dist 1.03, the network collapsed to F ~ e3 e3^T), while the
conditioned one went below the constant straight-ahead F (median epipolar distance 1.34 px vs 1.50 px).
In pixels the entries of F differ by (W / 2)^2 and the last row and column dominate the loss.
(The authors' public code builds K^-1 without the principal point, in effect a centred frame too.)

Optimizer: Adam (``lr``, ``weight_decay``), gradient norm clipped at ``grad_clip`` (1.0); the
learning rate is constant or follows a cosine to 0 at the last step (``schedule``), after
``warmup_steps`` of linear warm-up (computed from the step count, so resuming keeps it).

Validation (every epoch, or every ``val_every`` steps), the paper's metrics on ``val_points``
points per pair sampled *on the ground-truth geometry*: x_a uniform in image a, x_b the projection
of a uniform point of image b onto the epipolar line F_t x_a, so x_b^T F_gt x_a = 0 exactly (the
same for synthetic and KITTI pairs: KITTI has no dense correspondences, and for synthetic scenes
these points are exact too; a fixed generator makes them identical across validations):

- ``epi_abs``: mean |x_b^T F x_a| with F scaled to unit Frobenius norm, in model-input pixels;
- ``epi_sqr``: mean (x_b^T F x_a)^2, same F and points;
- ``sed_px``: median symmetric epipolar distance (pixels of the model input);
- ``f_dist``: mean min ||F -+ F_t|| of unit-norm matrices; ``loss``: the training loss;
- beside the network, two constants that read no image, on the same points: ``mean_f_sed_px``, the median SED of
  the mean F of the training pairs stepped on so far (:class:`TargetMean`, travels in ``last.pt``), and
  ``ahead_sed_px``, of straight-ahead motion (:func:`straight_ahead_input_f`); ``mean_f_p`` / ``ahead_p``:
  Wilcoxon's two-sided p of the per-pair median SEDs of the network against each.  The network beats a constant
  when its median SED is lower and p < 0.05 (:func:`beats`); unless it beats both, each validation's line, the
  end of ``fviz train`` and ``train.rrd`` (``val/verdict``) say "the model is no better than the constant"
  (:func:`versus_constants`).  Measured: recipes/synthetic_small.toml ends at 1.641 px against 1.642 / 1.642 px
  (no better); recipes/synthetic_bundled.toml at 1.785 px against 3.014 / 2.672 px (H200, its recipe header).

Outputs in ``train.out_dir``: ``last.pt`` (full checkpoint: model, optimizer, recipe, metrics, step,
code version, the curves; rewritten atomically every ``checkpoint_every`` steps and at each
validation), ``model.pt`` (weights only, ``export_dtype``, written at the end: the file to ship), and
``train.rrd`` (Rerun recording of the curves ``train/*`` and ``val/*`` on the ``step`` timeline, each validation's
verdict against the constants (``val/verdict``), and of the
network on ``train.watch_pairs`` fixed validation pairs every ``train.watch_every`` steps or at each checkpoint:
its epipolar lines beside the ground truth's, through :func:`fviz.log_training_step`;
rewritten complete, footer included, under a temporary name and renamed into place at each
checkpoint: after SIGKILL it is the last checkpoint's complete recording).  ``train/loss`` is the
loss of each training batch in training mode (dropout on, BatchNorm on the batch's statistics);
``val/loss`` the mean over the held-out validation pairs in eval mode (no dropout, BatchNorm's
running statistics, which lag behind the weights early in a run: a large gap in the first
hundred steps is that, not overfitting).  Resuming (``resume=True``, CLI ``--resume``) continues
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

Device: ``train.device = "auto"`` picks CUDA when available, else the CPU.  On CUDA ``amp = "auto"``
uses bf16 autocast where supported, else fp16 with a gradient scaler; on the CPU training runs in
float32.  Data loading uses ``num_workers`` worker processes (synthetic scenes with 0 workers are
rendered in the main process on the training device).  ``data.cache = true`` renders / loads every
pair once (with those workers) into memory (on the GPU when it fits in a quarter of the free GPU
memory) and trains all epochs from there; under torchrun every process caches the whole set.

Multi-GPU: run under torchrun, e.g. ``torchrun --nproc_per_node 4 -m fviz train RECIPE`` (any
launcher that sets WORLD_SIZE / RANK / LOCAL_RANK).  With WORLD_SIZE > 1 the model is wrapped in
DistributedDataParallel (NCCL on CUDA, gloo on CPU), each process takes a disjoint slice of every
epoch with ``train.batch_size`` pairs per step (the global batch is WORLD_SIZE times larger: scale
``lr`` accordingly), and rank 0 alone validates, logs, and writes checkpoints.
"""

from __future__ import annotations

import json
import math
import os
import signal
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from fviz.errors import FvizError
from fviz.train.recipe import Recipe, load_recipe, resolve_path


class TrainingInterrupted(FvizError):
    """Ctrl-C or SIGTERM stopped training after a complete step; ``checkpoint`` holds that step."""

    exit_code = 130

    def __init__(self, message: str, step: int, checkpoint: Path | None, signal_name: str):
        super().__init__(message)
        self.step = step
        self.checkpoint = checkpoint
        self.signal_name = signal_name


class _StopRequests:
    """SIGINT / SIGTERM during training: the first one asks the loop to stop after the current step
    (it then checkpoints and raises :class:`TrainingInterrupted`); a second one interrupts at once
    (KeyboardInterrupt; ``last.pt`` is then the previous checkpoint, complete).  Only in the main
    thread of a single-process run: under torchrun the launcher forwards signals to every rank."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self, enabled: bool):
        import threading

        self.enabled = enabled and threading.current_thread() is threading.main_thread()
        self.received: str | None = None
        self._previous: dict = {}

    def _handle(self, signum, frame) -> None:
        if self.received is not None:
            raise KeyboardInterrupt
        self.received = signal.Signals(signum).name

    def __enter__(self) -> "_StopRequests":
        if self.enabled:
            for sig in self.SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


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


# ----------------------------------------------------------------------------------------------- loss & metrics


def _to_conditioned(F: torch.Tensor, input_hw: tuple[int, int], norm: str) -> torch.Tensor:
    from fviz.models.heads import conditioning_matrix
    from fviz.models.normalization import normalize_f

    T_inv = torch.linalg.inv(conditioning_matrix(input_hw, dtype=F.dtype, device=F.device))
    return normalize_f(T_inv.transpose(0, 1) @ F @ T_inv, norm, strict=False)


def f_loss(F_pred: torch.Tensor, F_t: torch.Tensor, norm: str, l1_weight: float = 1.0, l2_weight: float = 1.0,
           frame: str = "pixel", input_hw: tuple[int, int] | None = None) -> torch.Tensor:
    """L1 + L2 between normalized matrices, sign-invariant for fbn/abs.  (B, 3, 3) x 2 -> scalar."""
    F_pred, F_t = F_pred.float(), F_t.float()
    if frame == "conditioned":
        F_pred, F_t = _to_conditioned(F_pred, input_hw, norm), _to_conditioned(F_t, input_hw, norm)

    def per_pair(d: torch.Tensor) -> torch.Tensor:
        return l1_weight * d.abs().mean((-1, -2)) + l2_weight * d.square().mean((-1, -2))

    loss = per_pair(F_pred - F_t)
    if norm != "etr":
        loss = torch.minimum(loss, per_pair(F_pred + F_t))
    return loss.mean()


def sed_loss(F_pred: torch.Tensor, xa: torch.Tensor, xb: torch.Tensor, knee_px: float = 1.0) -> torch.Tensor:
    """Mean Charbonnier of the symmetric epipolar distance of ``F_pred`` on correspondences (x_b^T F_t x_a = 0):
    ~SED^2 / 2 below ``knee_px``, ~SED above it.  Scale- and sign-invariant in F.  (B, 3, 3), (B, n, 3) x 2 -> scalar."""
    sed = epipolar_metrics(F_pred, xa, xb)["sed"]
    return (knee_px * (torch.sqrt(1.0 + (sed / knee_px).square()) - 1.0)).mean().float()


def sample_points_on_geometry(F_t: torch.Tensor, input_hw: tuple[int, int], n: int, generator: torch.Generator
                              ) -> tuple[torch.Tensor, torch.Tensor]:
    """Points with x_b^T F_t x_a = 0: x_a uniform, x_b = a uniform point projected on F_t x_a.  -> (B, n, 3) x 2, float64."""
    B = F_t.shape[0]
    H, W = input_hw
    scale = torch.tensor([W - 1, H - 1], dtype=torch.float64)
    xa = torch.rand(B, n, 2, generator=generator, dtype=torch.float64) * scale
    p = torch.rand(B, n, 2, generator=generator, dtype=torch.float64) * scale
    one = torch.ones(B, n, 1, dtype=torch.float64)
    xa = torch.cat([xa, one], -1).to(F_t.device)
    p = torch.cat([p, one], -1).to(F_t.device)
    lines = xa @ F_t.double().transpose(-1, -2)  # (B, n, 3): l = F x_a
    ab2 = lines[..., :2].square().sum(-1, keepdim=True).clamp_min(1e-300)
    dist = (lines * p).sum(-1, keepdim=True)
    xb = p.clone()
    xb[..., :2] = p[..., :2] - dist * lines[..., :2] / ab2
    return xa, xb


def epipolar_metrics(F_pred: torch.Tensor, xa: torch.Tensor, xb: torch.Tensor) -> dict[str, torch.Tensor]:
    """Per-point |x_b^T F x_a| (unit-Frobenius F) and symmetric epipolar distance.  -> (B, n) each."""
    F = F_pred.double()
    F = F / F.flatten(1).norm(dim=1).clamp_min(1e-300)[:, None, None]
    Fxa = xa @ F.transpose(-1, -2)
    Ftxb = xb @ F
    r = (xb * Fxa).sum(-1)
    d_b = r.abs() / Fxa[..., :2].norm(dim=-1).clamp_min(1e-300)
    d_a = r.abs() / Ftxb[..., :2].norm(dim=-1).clamp_min(1e-300)
    return {"abs": r.abs(), "sed": 0.5 * (d_a + d_b)}


def f_distance_t(F_pred: torch.Tensor, F_t: torch.Tensor) -> torch.Tensor:
    a = F_pred.double().flatten(1)
    b = F_t.double().flatten(1)
    a = a / a.norm(dim=1, keepdim=True).clamp_min(1e-300)
    b = b / b.norm(dim=1, keepdim=True).clamp_min(1e-300)
    return torch.minimum((a - b).norm(dim=1), (a + b).norm(dim=1))


# ----------------------------------------------------------------------------------------------- helpers


class _Batches(torch.utils.data.Sampler):
    """A sampler whose batches (lists of indices) can be swapped between epochs (persistent workers)."""

    def __init__(self, batches: list[list[int]] | None = None):
        self.batches = batches or []

    def __iter__(self):
        return iter(list(self.batches))

    def __len__(self) -> int:
        return len(self.batches)


def _worker_ignores_interrupts(_: int) -> None:
    """Workers leave Ctrl-C to the main process (which stops after the step and checkpoints)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _loader(ds, sampler: _Batches, num_workers: int, pin: bool) -> torch.utils.data.DataLoader:
    return torch.utils.data.DataLoader(
        ds, batch_size=None, sampler=sampler, num_workers=num_workers, pin_memory=pin, persistent_workers=num_workers > 0,
        worker_init_fn=_worker_ignores_interrupts if num_workers > 0 else None,
    )


def resolve_device(name: str) -> torch.device:
    name = (name or "auto").lower()
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise FvizError(f"train.device {name!r} is not a device (auto, cpu, cuda, cuda:N)") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise FvizError(f"train.device is {name!r} but CUDA is not available here; use 'auto' or 'cpu'")
    return dev


def _amp_dtype(amp: str, device: torch.device) -> torch.dtype | None:
    if device.type != "cuda" or amp == "off":
        return None
    if amp == "bf16" or (amp == "auto" and torch.cuda.is_bf16_supported()):
        return torch.bfloat16
    return torch.float16


class _Curves:
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
        # the watched validation pairs (fviz.log_training_step): the pairs, and the network's F on them per frame
        self.pairs: list = []
        self.frames: list[tuple[int, list]] = [(int(s), F) for s, F in (watch or [])]
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

    def watch(self, step: int, F_pred: torch.Tensor) -> None:
        """Keep the network's F (B, 3, 3) on the watched pairs at ``step`` (one frame; a step's last one counts)."""
        F = F_pred.detach().float().cpu().tolist()
        self.frames = [f for f in self.frames if f[0] != step] + [(int(step), F)]

    def snapshot(self) -> None:
        """Make ``path`` a complete recording of everything logged so far (atomic rename)."""
        from fviz.record.layout import training_blueprint, training_style
        from fviz.record.writer import RecordingWriter

        rr = self.rr
        names = [str(i) for i in range(len(self.pairs))]
        bp = training_blueprint(names, [(p.size_a, p.size_b) for p in self.pairs], curves=True)
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
                for step, F in self.frames:
                    log_training_step(rec, step, self.pairs, F, names, blueprint=False)
                self.watch_seconds += time.perf_counter() - t0

    close = snapshot


class _Quiet:
    notes: list = []

    def log(self, *a, **k):
        pass

    snapshot = close = note = log

    def state(self) -> dict:
        return {}


def _dist_setup(device_name: str) -> tuple[int, int, torch.device]:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1, resolve_device(device_name)
    import torch.distributed as dist

    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    use_cuda = torch.cuda.is_available() and device_name.lower() in ("auto", "cuda")
    if use_cuda:
        torch.cuda.set_device(local_rank)
        device = torch.device("cuda", local_rank)
    else:
        device = torch.device("cpu")
    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if use_cuda else "gloo")
    return dist.get_rank(), dist.get_world_size(), device


# ----------------------------------------------------------------------------------------------- the loop


VALIDATION_FIGURES = ("loss", "epi_abs", "epi_sqr", "sed_px", "f_dist")  # the network's; then each constant's
NO_BETTER = "the model is no better than the constant"
CONSTANTS = ("mean_f", "ahead")  # the constants every validation sets the network beside (CONSTANT_NAMES: how they read)
CONSTANT_NAMES = {"mean_f": "the training pairs' mean F", "ahead": "straight-ahead motion"}
BEATS_P = 0.05  # the network beats a constant when Wilcoxon's test of the per-pair median SEDs finds it lower at p < 0.05


@torch.no_grad()
def validate(model, loader, recipe: Recipe, device: torch.device, amp_dtype: torch.dtype | None,
             mean_f: torch.Tensor | None = None) -> dict[str, float]:
    """The validation metrics of ``model`` over ``loader`` (see the module docstring), beside two constants that
    read no image on the same points: ``mean_f`` (the training pairs' mean F, :class:`TargetMean`; without it the
    validation targets' own mean, an oracle) and straight-ahead motion (:func:`straight_ahead_input_f`).
    ``{c}_sed_px``: a constant's median SED; ``{c}_p``: Wilcoxon's two-sided p of the per-pair median SEDs of the
    network against it (:func:`versus_constants` reads them)."""
    norm = recipe.model.variant.rsplit("-", 1)[1]
    t = recipe.train
    was_training = model.training
    model.eval()
    gen = torch.Generator().manual_seed(12345)
    loss_sum, n_pairs, f_sum = 0.0, 0, 0.0
    abs_all, sqr_all, sed_all, targets = [], [], [], []  # targets: (F_t, xa, xb) for the constants' SED
    try:
        for img_a, img_b, F_t in loader:
            img_a, img_b, F_t = img_a.to(device), img_b.to(device), F_t.to(device)
            with torch.autocast(device.type, dtype=amp_dtype or torch.float32, enabled=amp_dtype is not None):
                F_pred = model(img_a, img_b, strict_norm=False)
            B = F_t.shape[0]
            loss_sum += float(f_loss(F_pred, F_t, norm, t.l1_weight, t.l2_weight, t.loss_frame, recipe.input_hw)) * B
            n_pairs += B
            xa, xb = sample_points_on_geometry(F_t, recipe.input_hw, recipe.data.val_points, gen)
            m = epipolar_metrics(F_pred, xa, xb)
            abs_all.append(m["abs"].flatten().cpu())
            sqr_all.append(m["abs"].square().flatten().cpu())
            sed_all.append(m["sed"].cpu())
            targets.append((F_t.double().cpu(), xa.cpu(), xb.cpu()))
            f_sum += float(f_distance_t(F_pred, F_t).sum())
    finally:
        model.train(was_training)
    if n_pairs == 0:
        return {}
    sed = torch.cat(sed_all)
    out = {
        "loss": loss_sum / n_pairs,
        "epi_abs": float(torch.cat(abs_all).mean()),
        "epi_sqr": float(torch.cat(sqr_all).mean()),
        "sed_px": _median(sed),
        "f_dist": f_sum / n_pairs,
    }
    constants = {"mean_f": mean_f if mean_f is not None else mean_target(torch.cat([t[0] for t in targets])),
                 "ahead": straight_ahead_input_f(recipe.input_hw)}
    for name, F_c in constants.items():
        sed_c = constant_sed(F_c, targets)
        out[f"{name}_sed_px"] = _median(sed_c)
        out[f"{name}_p"] = _paired_p(sed, sed_c)
    return out


def _median(sed: torch.Tensor) -> float:
    sed = sed.flatten()
    sed = sed[torch.isfinite(sed)]
    return float(sed.median()) if sed.numel() else float("nan")


def _paired_p(sed: torch.Tensor, sed_c: torch.Tensor) -> float:
    """Wilcoxon's two-sided p of the per-pair median SEDs (B, n) x 2 (:func:`fviz.compare.wilcoxon_signed_rank`)."""
    from fviz.compare import wilcoxon_signed_rank

    d = (sed.nanmedian(dim=1).values - sed_c.nanmedian(dim=1).values).numpy()
    return float(wilcoxon_signed_rank(d).p)


def mean_target(F_t: torch.Tensor) -> torch.Tensor:
    """The mean of targets (B, 3, 3) up to scale and sign: unit Frobenius, signs aligned with the first, made rank 2."""
    F = F_t.double().flatten(1)
    F = F / F.norm(dim=1, keepdim=True).clamp_min(1e-300)
    F = F * torch.where(F @ F[0] < 0, -1.0, 1.0)[:, None].to(F)
    return _rank2(F.mean(0).reshape(3, 3))


def _rank2(F: torch.Tensor) -> torch.Tensor:
    U, S, Vh = torch.linalg.svd(F.double())
    F = U @ torch.diag(torch.stack([S[0], S[1], torch.zeros_like(S[2])])) @ Vh
    return F / F.norm().clamp_min(1e-300)


def straight_ahead_input_f(input_hw: tuple[int, int]) -> torch.Tensor:
    """F of pure forward motion (R = I, t = z) in model-input pixels, for KITTI's camera scaled to the input (the
    synthetic scenes' camera, :func:`fviz.data.synthetic.intrinsics`): K^-T [z]x K^-1 ~ [(cx, cy, 1)]x, lines
    through the principal point.  Unit Frobenius, float64."""
    H, W = int(input_hw[0]), int(input_hw[1])
    try:
        from fviz.data.synthetic import intrinsics

        K = intrinsics(W, H)
        cx, cy = float(K[0, 2]), float(K[1, 2])
    except ImportError:  # the image centre
        cx, cy = (W - 1) / 2, (H - 1) / 2
    F = torch.tensor([[0.0, -1.0, cy], [1.0, 0.0, -cx], [-cy, cx, 0.0]], dtype=torch.float64)
    return F / F.norm()


def constant_sed(F_c: torch.Tensor, targets: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]) -> torch.Tensor:
    """The SED (B, n) of one constant F on the validation points; ``targets``: per batch (F_t, xa, xb (B, n, 3))."""
    F_c = F_c.double().cpu()
    return torch.cat([epipolar_metrics(F_c.expand(len(xa), 3, 3), xa.double(), xb.double())["sed"] for _, xa, xb in targets])


def constant_sed_px(targets: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]) -> float:
    """The median SED on the validation points of the validation targets' own mean F (an oracle: it has seen the
    labels). ``targets``: per batch (F_t (B, 3, 3), xa, xb (B, n, 3))."""
    return _median(constant_sed(mean_target(torch.cat([t[0] for t in targets])), targets))


class TargetMean:
    """The running mean of the training targets the loop has stepped on, unit Frobenius, signs aligned with
    ``ref`` (the training set's first target, as :func:`fviz.estimators.baselines.mean_fundamental` aligns
    with the first of its matrices): the constant F of the training data, what a network that ignores the
    images converges to.  Summed on the training device (no host sync per step); it travels in the
    checkpoint (:meth:`state`)."""

    def __init__(self, state: dict | None = None, ref: torch.Tensor | None = None):
        self.ref = self.sum = self._ref = None
        self.n = 0
        if ref is not None:
            F = ref.detach().double().cpu().flatten()
            self.ref = F / F.norm().clamp_min(1e-300)
        if state and state.get("n"):
            self.ref = torch.tensor(state["ref"], dtype=torch.float64)
            self.sum = torch.tensor(state["sum"], dtype=torch.float64)
            self.n = int(state["n"])

    def add(self, F_t: torch.Tensor) -> None:
        F = F_t.detach().flatten(1)
        F = F.float() if F.device.type == "mps" else F.double()  # MPS has no float64
        F = F / F.norm(dim=1, keepdim=True).clamp_min(1e-30)
        if self.ref is None:
            self.ref = F[0].double().cpu()
        if getattr(self, "_ref", None) is None or self._ref.device != F.device:
            self._ref = self.ref.to(F)  # once per device: no copy per step
        ref = self._ref
        F = F * torch.where(F @ ref < 0, -1.0, 1.0)[:, None]
        s = F.sum(0)
        self.sum = s if self.sum is None else self.sum.to(s) + s
        self.n += F.shape[0]

    def F(self) -> torch.Tensor | None:
        """The rank-2 mean (3, 3), float64 on the CPU; None before the first step."""
        return _rank2(self.sum.double().cpu().reshape(3, 3)) if self.n else None

    def state(self) -> dict:
        if not self.n:
            return {}
        return {"ref": self.ref.tolist(), "sum": self.sum.double().cpu().tolist(), "n": self.n}


def beats(metrics: dict[str, float], constant: str) -> bool:
    """Whether the validation's network beats ``constant`` ("mean_f" or "ahead"): a lower median SED than the
    constant's, and Wilcoxon's test of the per-pair median SEDs finds a difference (p < BEATS_P)."""
    sed, c, p = (metrics.get(k, math.nan) for k in ("sed_px", f"{constant}_sed_px", f"{constant}_p"))
    return bool(sed < c and p < BEATS_P)


def versus_constants(metrics: dict[str, float], what: str = "validation") -> str:
    """One line setting the network beside both constants: "the model beats both constants: ..." or "the model
    is no better than the constant: validation median SED 1.648 px vs 1.651 px for the training pairs' mean F
    (p 0.41) and 1.503 px for straight-ahead motion (p 0.02)"; "" when the metrics lack the constants (a
    checkpoint of an older fviz)."""
    present = [c for c in CONSTANTS if f"{c}_sed_px" in metrics]
    if "sed_px" not in metrics or not present:
        return ""
    figures = " and ".join(f"{metrics[f'{c}_sed_px']:.4g} px for {CONSTANT_NAMES[c]} (p {metrics.get(f'{c}_p', math.nan):.2g})"
                           for c in present)
    lost = [c for c in present if not beats(metrics, c)]
    head = (NO_BETTER if lost else
            f"the model beats {'both constants' if len(present) > 1 else 'the constant'}")
    return f"{head}: {what} median SED {metrics['sed_px']:.4g} px vs {figures}"


def train(  # noqa: C901, PLR0915 (issue 41: to split into losses / state / curves / loop)
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
    from fviz.train.checkpoint import (
        atomic_save,
        code_version,
        export_weights,
        load_into,
        make_checkpoint,
        read_checkpoint,
    )
    from fviz.train.data import epoch_batches, make_datasets

    t_start = time.perf_counter()
    if not isinstance(recipe, Recipe):
        recipe = load_recipe(recipe)
    t = recipe.train
    rank, world, device = _dist_setup(t.device)
    main = rank == 0
    norm = recipe.model.variant.rsplit("-", 1)[1]
    out_dir = output_dir(recipe)
    ckpt_path = out_dir / "last.pt"
    if main:
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise FvizError(f"train.out_dir {out_dir}: cannot create it ({exc.strerror})") from None
        if not os.access(out_dir, os.W_OK):
            raise FvizError(f"train.out_dir {out_dir}: not writable")
    check_fresh(out_dir, resume)

    if t.threads:
        torch.set_num_threads(t.threads)
    torch.manual_seed(t.seed + rank)
    model = FNet.from_config(recipe.fnet_config()).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=t.lr, weight_decay=t.weight_decay)
    amp_dtype = _amp_dtype(t.amp, device)
    scaler = torch.amp.GradScaler("cuda", enabled=amp_dtype == torch.float16)

    if t.init and not resume:
        load_into(model, read_checkpoint(resolve_path(t.init)), what=f"train.init {t.init}")
    step = epoch = batch_in_epoch = 0
    history: list[dict[str, Any]] = []
    recording_id = str(uuid.uuid4())
    curve_state: dict = {}
    watch_state: list = []
    note_state: list = []
    mean_state: dict = {}
    if resume:
        if not ckpt_path.exists():
            raise FvizError(f"--resume: no checkpoint to resume at {ckpt_path}")
        ckpt = read_checkpoint(ckpt_path)
        load_into(model, ckpt, what=str(ckpt_path))
        if ckpt.get("optimizer_state") is None:
            raise FvizError(f"{ckpt_path}: holds no optimizer state (an exported weights file?); cannot resume from it")
        opt.load_state_dict(ckpt["optimizer_state"])
        if ckpt.get("scaler_state") and scaler.is_enabled():
            scaler.load_state_dict(ckpt["scaler_state"])
        step, epoch, batch_in_epoch = int(ckpt["step"]), int(ckpt["epoch"]), int(ckpt.get("batch_in_epoch", 0))
        history = list(ckpt.get("metrics", {}).get("history", []))
        recording_id = ckpt.get("recording_id") or recording_id
        curve_state = ckpt.get("curves") or {}
        watch_state = ckpt.get("watch") or []
        note_state = ckpt.get("notes") or []
        mean_state = ckpt.get("target_mean") or {}
        if ckpt.get("rng_state") is not None and world == 1:
            torch.set_rng_state(ckpt["rng_state"])

    loader_workers = t.num_workers
    if datasets is None:
        datasets = make_datasets(recipe, render_device=device if t.num_workers == 0 else "cpu")
        if recipe.data.cache:
            datasets = tuple(
                _cache(ds, what, t, progress and main, console, device) for ds, what in zip(datasets, ("training", "validation"))
            )
            loader_workers = 0  # in memory: indexing is cheaper than shipping batches from workers
    train_ds, val_ds = datasets
    if len(train_ds) == 0:
        raise FvizError("the training set is empty")
    steps_per_epoch = len(epoch_batches(len(train_ds), t.batch_size, t.seed, 0, rank, world))
    if steps_per_epoch == 0:
        raise FvizError(f"the training set ({len(train_ds)} pairs) is too small for {world} process(es)")
    total = t.epochs * steps_per_epoch
    if t.max_steps:
        total = min(total, t.max_steps)

    if not resume and t.t_norm_weight > 0:
        unit_translation(model, train_ds, t.batch_size, device)

    net = model
    if world > 1:
        net = torch.nn.parallel.DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None)

    pin = device.type == "cuda" and loader_workers > 0
    train_sampler = _Batches()
    train_loader = _loader(train_ds, train_sampler, loader_workers, pin)
    val_loader = None
    if main and val_ds is not None and len(val_ds):
        val_loader = _loader(val_ds, _Batches(epoch_batches(len(val_ds), t.batch_size, 0, 0, shuffle=False)), loader_workers, pin)

    if main and record:
        curves: Any = _Curves(out_dir / "train.rrd", recording_id, curve_state, watch_state, note_state)
        t0 = time.perf_counter()
        curves.pairs, watch_batch = watched_pairs(val_ds, t.watch_pairs, device)
        curves.watch_seconds += time.perf_counter() - t0
    else:
        watch_batch = None
        curves = _Quiet()
    recording = getattr(curves, "path", None)

    version = code_version() if main else None
    last_good: dict[str, Any] = {"path": ckpt_path if ckpt_path.exists() else None, "step": step if resume else None}
    losses: list[float] = []
    last_checkpoint = [step if resume else -1]
    metrics: dict[str, float] = {k: v for k, v in history[-1].items() if k not in ("step", "epoch")} if history else {}

    step_seconds = 0.0
    pending: list[torch.Tensor] = []  # losses of the steps since the last flush, still on the device
    point_rng = torch.Generator().manual_seed(t.seed * 7919 + step + rank)  # virtual correspondences of sed_loss
    best = [min((h[t.keep_best] for h in history if t.keep_best in h), default=math.inf) if t.keep_best else math.inf]
    last_grad: list[Any] = [None]
    # the constant F of the training pairs stepped on (validation's mean_f), signs aligned with the first pair's
    target_mean = TargetMean(mean_state, ref=None if mean_state else train_ds[[0]][2][0])

    def flush() -> None:
        """Bring the pending losses to the host (one sync), stop on a non-finite one, log them."""
        if not pending:
            return
        vals = torch.stack(pending).float()
        if world > 1:
            import torch.distributed as dist

            dist.all_reduce(vals)  # a NaN on any rank makes the mean NaN on all: all stop together
            vals = vals / world
        host = vals.tolist()
        first = step - len(host) + 1
        pending.clear()
        for i, value in enumerate(host):
            if not math.isfinite(value):
                where = (f"the last good checkpoint is {last_good['path']} (step {last_good['step']})"
                         if last_good["path"] is not None else "no checkpoint had been written yet")
                raise TrainingDiverged(
                    f"training stopped: the loss became {value} at step {first + i} (epoch {epoch + 1}); {where}. "
                    "Lower train.lr or check the data", first + i, last_good["path"],
                )
        losses.extend(host)
        for i, value in enumerate(host):
            if (first + i) % t.log_every == 0 or first + i == 1:
                curves.log(first + i, {"train/loss": value})
        grad = float(last_grad[0]) if last_grad[0] is not None else None
        curves.log(step, {"train/grad_norm": grad, "train/lr": opt.param_groups[0]["lr"]})
        bar.show(host[-1])

    def checkpoint() -> None:
        flush()
        if main:
            state = make_checkpoint(
                model, optimizer=opt, scaler=scaler, recipe=recipe.to_dict(), metrics={"last": metrics, "history": history},
                step=step, epoch=epoch, batch_in_epoch=batch_in_epoch, recording_id=recording_id, version=version,
            )
            state["curves"] = curves.state()
            state["notes"] = curves.notes
            state["target_mean"] = target_mean.state()
            if watch_batch is not None:
                if not t.watch_every:
                    watch()
                state["watch"] = curves.frames
            atomic_save(state, ckpt_path)
            last_good.update(path=ckpt_path, step=step)
            curves.snapshot()
        last_checkpoint[0] = step
        _barrier(world)

    def watch() -> None:
        """The network's F on the watched pairs at this step, for train.rrd (eval mode, as validation)."""
        t0 = time.perf_counter()
        was_training = model.training
        model.eval()
        with torch.no_grad(), torch.autocast(device.type, dtype=amp_dtype or torch.float32, enabled=amp_dtype is not None):
            F_pred = model(*watch_batch, strict_norm=False)
        model.train(was_training)
        curves.watch(step, F_pred)
        curves.watch_seconds += time.perf_counter() - t0

    def run_validation() -> None:
        nonlocal metrics
        flush()
        if main and val_loader is not None:
            metrics = validate(model, val_loader, recipe, device, amp_dtype, mean_f=target_mean.F())
            history.append({"step": step, "epoch": epoch, **metrics})
            curves.log(step, {f"val/{k}": v for k, v in metrics.items()})
            verdict = versus_constants(metrics)
            if verdict:
                curves.note(step, verdict)
            if t.keep_best and metrics.get(t.keep_best, math.inf) < best[0]:
                best[0] = metrics[t.keep_best]
                dtype = torch.float16 if t.export_dtype == "float16" else torch.float32
                atomic_save(make_checkpoint(model, recipe=recipe.to_dict(), metrics={"last": metrics, "history": history},
                                            step=step, epoch=epoch, recording_id=recording_id, dtype=dtype, version=version),
                            out_dir / "best.pt")
            if progress:
                recent = losses[-t.log_every:]
                train_part = (f"train loss {sum(recent) / len(recent):.4g} (mean of the last {len(recent)} batches, "
                              "training mode)") if recent else ""
                others = "  ".join(f"{k} {v:.4g}" for k, v in metrics.items() if k in VALIDATION_FIGURES and k != "loss")
                bar.print(f"step {step} (epoch {epoch}): {train_part} | val loss {metrics.get('loss', float('nan')):.4g} "
                          f"({len(val_ds)} held-out pairs, eval mode: BatchNorm running statistics, no dropout) | {others}")
                if verdict:
                    bar.print(f"step {step}: {verdict}")

    bar = _progress(progress and main, total, step, recipe.model.variant, console)
    done = step >= total
    last_validated = history[-1]["step"] if history else -1
    stop = _StopRequests(main and world == 1).__enter__()
    completed = False  # an error in flight is not hidden by one of closing train.rrd after it
    try:
        if watch_batch is not None and not any(f[0] == step for f in curves.frames):
            watch()  # where the network starts
        while not done:
            batches = epoch_batches(len(train_ds), t.batch_size, t.seed, epoch, rank, world)
            train_sampler.batches = batches[batch_in_epoch:]
            net.train()
            for img_a, img_b, F_t in train_loader:
                t_step = time.perf_counter()
                img_a = img_a.to(device, non_blocking=True)
                img_b = img_b.to(device, non_blocking=True)
                F_t = F_t.to(device, non_blocking=True)
                target_mean.add(F_t)
                with torch.autocast(device.type, dtype=amp_dtype or torch.float32, enabled=amp_dtype is not None):
                    F_pred = net(img_a, img_b)
                loss = f_loss(F_pred, F_t, norm, t.l1_weight, t.l2_weight, t.loss_frame, recipe.input_hw)
                if t.t_norm_weight > 0 and getattr(model.head, "t_raw_norm", None) is not None:
                    loss = loss + t.t_norm_weight * model.head.t_raw_norm.log().square().mean()
                if t.sed_weight > 0:
                    xa, xb = sample_points_on_geometry(F_t, recipe.input_hw, t.sed_points, point_rng)
                    loss = loss + t.sed_weight * sed_loss(F_pred, xa, xb)
                pending.append(loss.detach())  # checked at the next flush (no host sync per step)
                for group in opt.param_groups:
                    group["lr"] = lr_at(step, total, t)
                opt.zero_grad(set_to_none=True)
                scaler.scale(loss).backward()
                if t.grad_clip > 0:
                    scaler.unscale_(opt)
                    last_grad[0] = torch.nn.utils.clip_grad_norm_(model.parameters(), t.grad_clip)
                scaler.step(opt)
                scaler.update()
                step_seconds += time.perf_counter() - t_step  # the host's view: on a GPU, kernels may still run
                step += 1
                batch_in_epoch += 1
                bar.advance()
                if step % t.log_every == 0 or step == 1:
                    flush()
                if watch_batch is not None and t.watch_every and step % t.watch_every == 0:
                    watch()
                if t.val_every and step % t.val_every == 0:
                    run_validation()
                    last_validated = step
                    checkpoint()
                elif t.checkpoint_every and step % t.checkpoint_every == 0:
                    checkpoint()
                if step >= total:
                    done = True
                    break
                if stop.received:
                    break
            flush()
            if stop.received:
                if last_checkpoint[0] != step:
                    checkpoint()
                raise TrainingInterrupted(
                    f"{stop.received} at step {step} of {total}: checkpoint {ckpt_path} holds it", step, ckpt_path, stop.received
                )
            if batch_in_epoch >= len(batches):  # the epoch is complete
                epoch += 1
                batch_in_epoch = 0
                if not t.val_every:
                    run_validation()
                    last_validated = step
                checkpoint()
                done = done or epoch >= t.epochs
        flush()
        if last_validated != step:
            run_validation()
        if last_checkpoint[0] != step:
            checkpoint()
        weights = None
        if main:
            weights = export_weights(ckpt_path, out_dir / "model.pt", t.export_dtype)
            if held_out:
                from fviz.atomic import write_text
                from fviz.train.heldout import heldout_report

                report = heldout_report(recipe, weights)
                if report:
                    write_text(out_dir / "heldout.json", json.dumps(report, indent=1))
        completed = True
    finally:
        stop.__exit__()
        bar.close()
        if main:
            try:
                curves.close()
            except FvizError:  # a full disk (one line naming train.rrd); an error in flight goes first
                if completed:
                    raise
        if world > 1:
            import torch.distributed as dist

            dist.destroy_process_group()
    return TrainResult(
        out_dir=out_dir, checkpoint=ckpt_path, weights=weights, recording=recording, step=step, epoch=epoch,
        metrics=metrics, history=history, losses=losses, seconds=time.perf_counter() - t_start, step_seconds=step_seconds,
        watch_seconds=getattr(curves, "watch_seconds", 0.0),
    )


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


def check_fresh(out_dir: Path, resume: bool) -> None:
    """A fresh run (no --resume) into an out_dir holding last.pt or model.pt is refused: nothing is overwritten."""
    if not resume and (out_dir / "last.pt").exists():
        raise FvizError(
            f"{out_dir} already holds a checkpoint (last.pt): pass --resume to continue it, or choose another "
            "train.out_dir (e.g. --set train.out_dir=runs/NEW)"
        )
    if not resume and os.path.lexists(out_dir / "model.pt"):  # a finished run's weights, its last.pt removed
        raise FvizError(
            f"{out_dir} already holds a trained model (model.pt, without last.pt to resume): choose another "
            "train.out_dir (e.g. --set train.out_dir=runs/NEW), or move model.pt away to train here again"
        )


def output_dir(recipe: Recipe) -> Path:
    """The recipe's ``train.out_dir`` ({variant} filled in); FvizError when it exists and is not a folder."""
    out_dir = resolve_path(recipe.train.out_dir.replace("{variant}", recipe.model.variant))
    if out_dir.exists() and not out_dir.is_dir():
        raise FvizError(f"train.out_dir {out_dir}: exists and is not a folder (choose another, e.g. --set train.out_dir=runs/NEW)")
    return out_dir


def lr_at(step: int, total: int, t) -> float:
    """Learning rate of the step after ``step`` completed ones: linear warm-up, then constant or cosine to 0."""
    if t.warmup_steps and step < t.warmup_steps:
        return t.lr * (step + 1) / t.warmup_steps
    if t.schedule == "cosine":
        span = max(total - t.warmup_steps, 1)
        progress = min(max((step - t.warmup_steps) / span, 0.0), 1.0)
        return t.lr * 0.5 * (1.0 + math.cos(math.pi * progress))
    return t.lr


def _cache(ds, what: str, t, show: bool, console, device: torch.device):
    from fviz.train.data import CachedPairs

    if ds is None or len(ds) == 0:
        return ds
    t0 = time.perf_counter()
    if show:
        from rich.progress import Progress

        with Progress(console=console, transient=True) as bar:
            task = bar.add_task(f"caching {len(ds)} {what} pairs", total=len(ds))
            cached = CachedPairs(ds, max(t.batch_size, 32), t.num_workers, lambda done, n: bar.update(task, completed=done))
        bar.console.print(f"cached {len(ds)} {what} pairs ({cached.nbytes / 1e9:.2f} GB) in {time.perf_counter() - t0:.0f} s")
    else:
        cached = CachedPairs(ds, max(t.batch_size, 32), t.num_workers)
    if device.type == "cuda":  # keep it on the GPU when it takes at most a quarter of the free memory
        free, _ = torch.cuda.mem_get_info(device)
        if cached.nbytes < free / 4:
            cached.to(device)
    return cached


def _barrier(world: int) -> None:
    if world > 1:
        import torch.distributed as dist

        dist.barrier()


class _NoBar:
    def advance(self) -> None:
        pass

    def show(self, loss: float) -> None:
        pass

    def print(self, text: str) -> None:
        pass

    def close(self) -> None:
        pass


class _Bar:
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


def _progress(enabled: bool, total: int, start: int, name: str, console=None):
    return _Bar(total, start, name, console) if enabled else _NoBar()
