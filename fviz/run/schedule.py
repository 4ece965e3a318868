"""The order of a run's pairs: a frame-aware schedule (every frame detected once, by whichever worker is free; its
features handed to the later pairs that share it) and the deep estimators' batches (a GPU runs them in batches).
"""

from __future__ import annotations

import os
import time
from typing import Any

from fviz.data.pair import PairId
from fviz.run.config import RunConfig
from fviz.run.evaluator import PairTask, error_message


class FrameSchedule:
    """Frame-aware order of pair tasks: every frame detected exactly once, by whichever worker is free.

    A pair may start when none of its frames is being detected by a running task: it gets the
    features already detected and detects the rest itself (temporal step 1: pairs 0-1, 2-3, ... detect
    two frames each, and 1-2, 3-4, ... none, as soon as their neighbours are done). Only the first
    ``window`` waiting pairs are considered, and features are dropped when their last pair starts, so
    memory is bounded by the window, not the run. The split never changes a result: features depend
    on the image alone.
    """

    def __init__(self, todo: list[tuple[int, PairId]], window: int):
        self.waiting = list(todo)
        self.window = max(1, window)
        self.users: dict[str, int] = {}
        for _, pid in todo:
            for key in {pid.key_a, pid.key_b}:
                self.users[key] = self.users.get(key, 0) + 1
        self.features: dict[str, Any] = {}
        self.detecting: set[str] = set()

    def __len__(self) -> int:
        return len(self.waiting)

    def next_task(self) -> PairTask | None:
        """The first startable pair within the window, or None (all waiting, or none left)."""
        for pos, (index, pid) in enumerate(self.waiting[: self.window]):
            keys = {pid.key_a, pid.key_b}
            if keys & self.detecting:
                continue
            del self.waiting[pos]
            given = {k: self.features[k] for k in keys if k in self.features}
            detects = frozenset(keys - given.keys())
            for key in keys:
                self.users[key] -= 1
                if self.users[key] == 0:
                    self.features.pop(key, None)
            self.detecting |= detects
            return PairTask(index, pid, given, tuple(k for k in detects if self.users[k] > 0), detects)
        return None

    def done(self, task: PairTask, kept: dict) -> None:
        """A task finished: its kept features serve later pairs; a frame it failed to detect is free again."""
        self.detecting -= task.detects
        self.features.update({k: f for k, f in kept.items() if self.users[k] > 0})


def schedule_window(todo: list[tuple[int, PairId]], workers: int) -> int:
    """Waiting pairs the scheduler looks at: a few per worker for every pair that starts at one frame."""
    starts = {pid.key_a for _, pid in todo}
    return 4 * max(1, workers) * -(-len(todo) // max(1, len(starts)))


class DeepBatches:
    """The deep estimators of a run, evaluated in batches in the main process on one device (the GPU
    when CUDA is present): the workers get each pair's F with its task and never load the model.

    ``$FVIZ_DEEP_BATCH`` overrides the choice: a device ("cpu", "cuda:1") or "off" (each worker runs
    the model on its pairs on the CPU, the default without CUDA).
    """

    def __init__(self, config: RunConfig, device: str, size: int = 64):
        from fviz.estimators.deep import deep_batch_predictor
        from fviz.estimators.registry import display_name

        self.source = config.selection.source()
        self.size = size
        self.predictors = {display_name(n): deep_batch_predictor(n.partition(":")[2] or None, device)
                           for n in config.options.names if n.partition(":")[0] == "deep"}
        self.results: dict[int, dict] = {}

    @classmethod
    def of(cls, config: RunConfig) -> "DeepBatches | None":
        if not any(n.partition(":")[0] == "deep" for n in config.options.names):
            return None
        device = os.environ.get("FVIZ_DEEP_BATCH", "")
        if not device:
            import torch

            device = "cuda" if torch.cuda.is_available() else "off"
        return None if device == "off" else cls(config, device)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.predictors)

    def attach(self, task: PairTask, schedule: FrameSchedule) -> PairTask:
        """Give ``task`` its F of every deep estimator, predicting them with the next waiting pairs'."""
        if task.index not in self.results:
            self._predict([(task.index, task.pid), *schedule.waiting[: self.size - 1]])
        task.batched = self.results.pop(task.index)
        return task

    def _predict(self, pairs: list[tuple[int, PairId]]) -> None:
        from concurrent.futures import ThreadPoolExecutor

        pairs = [(i, pid) for i, pid in pairs if i not in self.results]

        def load(pid):
            try:
                pair = self.source.load(pid)
                pair.image_a, pair.image_b  # decoded here, in parallel (decoding releases the GIL)
                return pair
            except Exception as exc:
                return error_message(exc)

        with ThreadPoolExecutor(4) as pool:
            loaded = list(pool.map(load, [pid for _, pid in pairs]))
        for i, _ in pairs:
            self.results[i] = {}
        ok = [(i, p) for (i, _), p in zip(pairs, loaded) if not isinstance(p, str)]
        for (i, _), p in zip(pairs, loaded):
            if isinstance(p, str):
                self.results[i] = {name: (p, 0.0) for name in self.predictors}
        for name, predict in self.predictors.items():
            t0 = time.perf_counter()
            try:
                Fs = predict([p for _, p in ok])
            except Exception:  # one pair's failure (e.g. ETR of F33 = 0) must not fail the batch
                Fs = [self._one(predict, p) for _, p in ok]
            share = (time.perf_counter() - t0) / max(1, len(ok))
            for (i, _), F in zip(ok, Fs):
                self.results[i][name] = (F, share)

    @staticmethod
    def _one(predict, pair):
        try:
            return predict([pair])[0]
        except Exception as exc:
            return error_message(exc)


# ------------------------------------------------------------------------------ interrupts
