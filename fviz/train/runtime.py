"""Where and how a training run executes: the device and mixed precision, the processes of a torchrun launch,
the data loaders and each epoch's batches, the in-memory cache of the pairs, and Ctrl-C / SIGTERM.

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

import math
import os
import signal
import time
from typing import Any

import torch

from fviz.errors import FvizError
from fviz.train.recipe import Recipe


def resolve_device(name: str) -> torch.device:
    """``train.device``: "auto" (CUDA when available, else the CPU), "cpu", "cuda", "cuda:N"; FvizError otherwise."""
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


def autocast_dtype(amp: str, device: torch.device) -> torch.dtype | None:
    """The autocast dtype of ``train.amp`` on ``device``: bf16 where supported, else fp16; None off CUDA (float32)."""
    if device.type != "cuda" or amp == "off":
        return None
    if amp == "bf16" or (amp == "auto" and torch.cuda.is_bf16_supported()):
        return torch.bfloat16
    return torch.float16


def dist_setup(device_name: str) -> tuple[int, int, torch.device]:
    """(rank, world size, device) of this process; under torchrun (WORLD_SIZE > 1) it joins the process group."""
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


def barrier(world: int) -> None:
    """Wait for every rank (nothing in a single process)."""
    if world > 1:
        import torch.distributed as dist

        dist.barrier()


def epoch_batches(n: int, batch_size: int, seed: int, epoch: int, rank: int = 0, world: int = 1, shuffle: bool = True) -> list[list[int]]:
    """The batches (lists of indices) of one epoch: a seeded permutation, split across ranks, full batches only."""
    if shuffle:
        g = torch.Generator().manual_seed(int(seed) * 100_003 + int(epoch))
        order = torch.randperm(n, generator=g).tolist()
    else:
        order = list(range(n))
    order = order[rank::world][: n // world]  # the same number of batches on every rank
    nb = len(order) // batch_size if shuffle else math.ceil(len(order) / batch_size)
    if shuffle and nb == 0 and order:  # fewer pairs than one batch: one smaller batch
        return [order]
    return [order[i * batch_size : (i + 1) * batch_size] for i in range(nb)]


class Batches(torch.utils.data.Sampler):
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


def loader(ds, sampler: Batches, num_workers: int, pin: bool) -> torch.utils.data.DataLoader:
    """A DataLoader of whole batches (``ds[list]``, see :mod:`fviz.train.data`) in ``sampler``'s order."""
    return torch.utils.data.DataLoader(
        ds, batch_size=None, sampler=sampler, num_workers=num_workers, pin_memory=pin, persistent_workers=num_workers > 0,
        worker_init_fn=_worker_ignores_interrupts if num_workers > 0 else None,
    )


def cache_pairs(ds, what: str, t, show: bool, console, device: torch.device):
    """``ds`` loaded once into memory (:class:`fviz.train.data.CachedPairs`, ``data.cache``), on the GPU when it fits."""
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


class StopRequests:
    """SIGINT / SIGTERM during training: the first one asks the loop to stop after the current step
    (it then checkpoints and raises :class:`fviz.train.loop.TrainingInterrupted`); a second one interrupts at once
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

    def __enter__(self) -> "StopRequests":
        if self.enabled:
            for sig in self.SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def training_sets(recipe: Recipe, datasets: tuple[Any, Any] | None, device: torch.device, show: bool, console: Any
                  ) -> tuple[tuple[Any, Any], int]:
    """(train, val): the caller's, or the recipe's (kept in memory with ``data.cache``); and the loaders' workers."""
    from fviz.train.splits import make_datasets

    t = recipe.train
    loader_workers = t.num_workers
    if datasets is None:
        datasets = make_datasets(recipe, render_device=device if t.num_workers == 0 else "cpu")
        if recipe.data.cache:
            datasets = tuple(
                cache_pairs(ds, what, t, show, console, device) for ds, what in zip(datasets, ("training", "validation"))
            )
            loader_workers = 0  # in memory: indexing is cheaper than shipping batches from workers
    train_ds, val_ds = datasets
    if len(train_ds) == 0:
        raise FvizError("the training set is empty")
    return (train_ds, val_ds), loader_workers


def total_steps(t, n_train: int, rank: int, world: int) -> int:
    """The run's last step: ``epochs`` epochs of this rank's batches, at most ``max_steps``."""
    steps_per_epoch = len(epoch_batches(n_train, t.batch_size, t.seed, 0, rank, world))
    if steps_per_epoch == 0:
        raise FvizError(f"the training set ({n_train} pairs) is too small for {world} process(es)")
    total = t.epochs * steps_per_epoch
    return min(total, t.max_steps) if t.max_steps else total
