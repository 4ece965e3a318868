"""Evaluating the pairs of a run: one PairEvaluator per worker process, a frame-aware schedule (every
frame detected once), interrupts (SIGINT, SIGTERM), resume, and the whole ``run_eval``."""

from __future__ import annotations

import contextlib
import os
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

from fviz.atomic import WriteError
from fviz.data.pair import PairId
from fviz.errors import FvizError
from fviz.lock import locked
from fviz.run.config import MIN_PAIRS_PER_WORKER, RESULTS_FILE, RunConfig, prepare
from fviz.run.evaluator import CACHE_FRESH, CACHE_NOTES, PairEvaluator, PairTask, new_record
from fviz.run.hloc_cache import CacheWriter
from fviz.run.prestart import WORKER_PRELOAD
from fviz.run.reports import write_reports
from fviz.run.schedule import DeepBatches, FrameSchedule, schedule_window
from fviz.run.store import (
    ResultStore,
    RunOutcome,
    merge_record,
    payload_path,
    read_config,
    read_records,
    write_config,
)
from fviz.run.worker import DEEP_PRELOAD


class Interrupts:
    """SIGINT and SIGTERM during a run (SIGTERM is treated as Ctrl-C).

    The first stops starting pairs and lets those in flight finish; the second abandons them (an
    estimator that hangs cannot hold the run); the third exits at once, writing nothing more. While
    the reports are written, the first is noted and the second stops them (each report is replaced
    only when complete). Handlers print one line and count; from ``raise_from`` on they also raise
    KeyboardInterrupt where the main thread runs (it evaluates pairs itself with one worker, or
    writes reports); the worker pool's loop polls ``count`` instead.
    """

    SIGNALS = ("SIGINT", "SIGTERM")
    MESSAGES = {
        ("pairs", 1): "stopping after the pairs in flight (interrupt again to abandon them)",
        ("pairs", 2): "abandoning the pairs in flight; writing the reports (interrupt again to exit at once)",
        ("reports", 1): "finishing the reports first (interrupt again to stop)",
        ("reports", 2): "stopping the reports; the previous versions stay (interrupt again to exit at once)",
    }

    def __init__(self):
        self.count = 0
        self.stage = "pairs"
        self.raise_from: int | None = None
        self._previous: dict = {}

    def __enter__(self) -> "Interrupts":
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            for name in self.SIGNALS:
                sig = getattr(signal, name)
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        import signal

        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _handle(self, signum, frame) -> None:
        import signal

        self.count += 1
        name = signal.Signals(signum).name
        if self.count >= 3:
            os.write(2, f"\n{name}: interrupted three times, exiting now (finish with --resume)\n".encode())
            os._exit(130)
        os.write(2, f"\n{name}: {self.MESSAGES[self.stage, self.count]}\n".encode())  # no Python buffer: safe here
        if self.raise_from is not None and self.count >= self.raise_from:
            raise KeyboardInterrupt


# ------------------------------------------------------------------------------ workers


class WorkerPool:
    """``n`` worker processes, one task each at a time, over pipes. They start (and import) at once and
    get the run's configuration later (:meth:`configure`). A worker that dies fails its pair (recorded)
    and is replaced; all of them die with the main process."""

    isolating = False  # True: one worker for a small run, so that a crash in a user's estimator fails only its pair

    def __init__(self, n: int, preload: tuple[str, ...] = WORKER_PRELOAD):
        from fviz.run import prestart

        self.preload = preload
        self.setup: tuple | None = None
        self.tasks: dict[int, PairTask] = {}  # worker slot -> its running task
        self.workers = prestart.take(n)  # those the command line started (fviz.run.prestart; a deep model loads later)
        self.workers += [self._start() for _ in range(n - len(self.workers))]
        self._ready = [False] * n

    def __len__(self) -> int:
        return len(self.workers)

    def _start(self):
        from fviz.run.prestart import spawn_worker

        proc, parent = spawn_worker(self.preload)  # workers start with Ctrl-C ignored
        if self.setup is not None:
            parent.send(self.setup)
        return proc, parent

    def configure(self, config: RunConfig, out_dir: Path, n: int, batched: tuple[str, ...] = ()) -> None:
        """Keep ``n`` workers and send them the run's configuration (and which estimators run in batches)."""
        self.close(kill=True, slots=range(n, len(self.workers)))
        del self.workers[n:], self._ready[n:]
        self.setup = (config.to_dict(), str(out_dir), batched)
        for _, conn in self.workers:
            conn.send(self.setup)

    def idle(self) -> list[int]:
        return [i for i in range(len(self.workers)) if i not in self.tasks and self._ready[i]]

    def submit(self, slot: int, task: PairTask) -> None:
        self.tasks[slot] = task
        self.workers[slot][1].send(task)

    def wait(self, timeout: float) -> list[tuple[PairTask, dict | None, dict]]:
        """Finished tasks as (task, record or None if its worker died, kept features)."""
        from multiprocessing.connection import wait

        conns = {w[1]: i for i, w in enumerate(self.workers)}
        sentinels = {w[0].sentinel: i for i, w in enumerate(self.workers)}
        out = []
        ready = wait([*conns, *sentinels], timeout)
        for slot in sorted({conns.get(r, sentinels.get(r)) for r in ready}):
            proc, conn = self.workers[slot]
            try:
                kind, payload = conn.recv() if conn in ready else (None, None)
            except (EOFError, OSError):
                kind, payload = None, None
            if kind == "ready":
                self._ready[slot] = True
            elif kind == "failed":
                raise FvizError(f"worker start-up: {payload}")
            elif kind == "raised":
                raise payload
            elif kind == "done":
                task = self.tasks.pop(slot)
                out.append((task, *payload))
            else:  # the worker died (killed, out of memory, a crash in native code)
                proc.join()
                conn.close()
                task = self.tasks.pop(slot, None)
                if task is None and not self._ready[slot]:
                    raise FvizError(f"a worker process died while starting (exit code {proc.exitcode})")
                if task is not None:
                    out.append((task, None, {}))
                self.workers[slot], self._ready[slot] = self._start(), False
        return out

    def close(self, kill: bool = False, slots=None) -> None:
        chosen = [self.workers[i] for i in (range(len(self.workers)) if slots is None else slots)]
        for proc, conn in chosen:
            with contextlib.suppress(OSError, ValueError):
                proc.kill() if kill else conn.send(None)
        for proc, conn in chosen:
            proc.join()
            conn.close()


def start_pool(config: RunConfig, workers: int, n_pairs: int) -> WorkerPool | None:
    """Worker processes for a run of ``n_pairs``, started before the run is prepared so that their
    imports overlap the main process's; None when one process does it (see :func:`pool_size`)."""
    from fviz.estimators.registry import is_user_spec
    from fviz.run import prestart

    n = pool_size(workers, n_pairs)
    isolate = n <= 1 and n_pairs > 0 and any(is_user_spec(s) for s in config.options.names)
    if n <= 1 and not isolate:
        prestart.take(0)  # those the command line started end here
        return None
    deep = any(name.partition(":")[0] == "deep" for name in config.options.names)
    pool = WorkerPool(max(n, 1), WORKER_PRELOAD + (DEEP_PRELOAD if deep else ()))
    pool.isolating = isolate  # a user's estimator that crashes (a segfault) fails its pair, not the run
    return pool


def usable_cores() -> int:
    """The cores this process may run on (a SLURM or container allocation, not the whole machine)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def pool_size(workers: int, n_pairs: int) -> int:
    """Worker processes worth starting: at most one per MIN_PAIRS_PER_WORKER pairs."""
    return min(workers, n_pairs // MIN_PAIRS_PER_WORKER)


def _execute(config: RunConfig, todo: list[tuple[int, PairId]], pool: WorkerPool | None, out_dir: Path,
             on_record: Callable[[dict], None], interrupts: Interrupts, only: dict[str, tuple[str, ...]] | None = None,
             on_started: Callable[[], None] = lambda: None) -> None:
    """Evaluate ``todo``, calling ``on_record`` in this process as each pair finishes; a pair named in
    ``only`` runs just those estimators; ``on_started`` once the first pair is under way (what this process
    does then no longer delays it).

    Without a pool (or for too few pairs): in this process. Else the pool, fed by a :class:`FrameSchedule`.
    After the first interrupt no pair starts; after the second, pairs in flight are abandoned.
    """
    workers = pool_size(len(pool) if pool else 1, len(todo))
    if pool is not None and pool.isolating and todo:
        workers = max(workers, 1)  # user estimators: in a worker process even for a few pairs (start_pool)
    schedule = FrameSchedule(todo, schedule_window(todo, workers))
    deep = DeepBatches.of(config) if todo else None
    batched = deep.names if deep else ()

    def next_task() -> PairTask | None:
        task = schedule.next_task()
        if task is not None:
            task.only = (only or {}).get(task.pid.name)
        return deep.attach(task, schedule) if deep and task else task

    if workers < 1 or (workers == 1 and not (pool is not None and pool.isolating)):
        if pool is not None:
            pool.close(kill=True)
        evaluator = PairEvaluator(config, out_dir, batched=batched)
        interrupts.raise_from = 2  # the second interrupt abandons the pair in flight
        on_started()
        try:
            while interrupts.count == 0 and (task := next_task()) is not None:
                rec, kept = evaluator.run_task(task)
                schedule.done(task, kept)
                on_record(rec)
        finally:
            interrupts.raise_from = None
        return
    pool.configure(config, out_dir, workers, batched)
    abandoned = started = False
    try:
        while True:
            if interrupts.count == 0:
                for slot in pool.idle():
                    task = next_task()
                    if task is None:
                        break
                    pool.submit(slot, task)
                    if not started:
                        started = True
                        on_started()
            if not pool.tasks and (interrupts.count or not len(schedule)):
                return
            if interrupts.count >= 2:
                abandoned = True
                return
            for task, rec, kept in pool.wait(timeout=0.2):
                if rec is None:
                    rec = {**new_record(config, task.index, task.pid), "error": "the worker process evaluating this pair died",
                           "detections": 0, "seconds": 0.0, "finished_at": time.time(), "worker": None}
                schedule.done(task, kept)
                on_record(rec)
    finally:
        pool.close(kill=abandoned or interrupts.count >= 2 or sys.exc_info()[0] is not None)


def _check_resume(out_dir: Path, config: RunConfig, resume: bool) -> None:
    old = read_config(out_dir)
    has_results = (Path(out_dir) / RESULTS_FILE).is_file()
    if not resume and has_results:
        raise FvizError(f"--out-dir {out_dir} already holds a run: add --resume to continue it, or choose another folder")
    if old is not None and has_results and old.comparable() != config.comparable():
        raise FvizError(f"--resume: {out_dir} was run with other options ({'; '.join(old.differences(config))}); "
                        "use the same flags or another --out-dir")
    if old is not None and has_results and old.shard != config.shard:
        raise FvizError(f"--resume: {out_dir} holds shard {old.shard}, not {config.shard}")


class _Progress:
    """eval's progress bar (rich), shown once the first pair is under way (:meth:`show`): rich's import (~0.1 s)
    then overlaps the workers' first detections instead of delaying them. Nothing at all when disabled."""

    def __init__(self, enabled: bool, total: int, completed: int):
        self.enabled, self.total, self.completed = enabled, total, completed
        self.bar = self.task = None

    def __enter__(self) -> "_Progress":
        return self

    def show(self) -> None:
        if self.enabled and self.bar is None:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            self.bar = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                                TextColumn("elapsed"), TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(),
                                console=Console(stderr=True))
            self.bar.start()
            self.task = self.bar.add_task("eval", total=self.total, completed=self.completed)

    def advance(self) -> None:
        self.show()
        if self.bar is not None:
            self.bar.advance(self.task)

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            self.bar.stop()


def run_eval(config: RunConfig, out_dir: str | Path, workers: int | None = None, resume: bool = False,
             progress: bool = True) -> RunOutcome:
    """:func:`_run_eval` holding the lock of ``out_dir`` (another run into it is refused)."""
    with locked(out_dir):
        _check_outputs(Path(out_dir))
        return _run_eval(config, out_dir, workers, resume, progress)


def _check_outputs(out_dir: Path) -> None:
    """Every file the run will replace is a regular file of the run folder (or not there yet): a folder, FIFO or a
    link planted to point outside it is refused now, before any pair is evaluated."""
    from fviz.atomic import target
    from fviz.run.config import CSV_FILE, PARQUET_FILE, RRD_FILE, RUN_FILE, SUMMARY_FILE, SUMMARY_JSON

    names = (RUN_FILE, CSV_FILE, PARQUET_FILE, SUMMARY_FILE, SUMMARY_JSON, RRD_FILE, "features.h5", "matches.h5")
    for name in names:
        target(out_dir / name)
    remove_leftovers(out_dir, names)


def remove_leftovers(folder: Path, names) -> None:
    """Remove the temporary files (``.NAME.tmp*``, regular files only) a killed run left beside ``names``: the
    caller holds the folder's lock, so no other fviz is writing them."""
    import stat

    for name in names:
        for p in folder.glob(f".{name}.tmp*"):
            with contextlib.suppress(OSError):
                if stat.S_ISREG(os.lstat(p).st_mode):
                    p.unlink()


def _run_eval(config: RunConfig, out_dir: str | Path, workers: int | None = None, resume: bool = False,
              progress: bool = True) -> RunOutcome:
    """Evaluate the pairs of ``config`` not yet in ``out_dir`` and regenerate the reports.

    Ctrl-C or SIGTERM stops after the pairs in flight (see :class:`Interrupts`); the reports then cover
    every finished pair and ``outcome.interrupted`` is set (``--resume`` finishes the run).
    """
    out_dir = Path(out_dir)
    workers = usable_cores() if workers is None else workers
    pool = start_pool(config, workers, len(config.pairs()))  # a bad selection fails here, before any process starts
    try:
        return _run(config, out_dir, pool, resume, progress)
    finally:
        if pool is not None:
            pool.close(kill=True)


def _preload_reports() -> None:
    """Import what the reports need in a thread while the pairs are evaluated (not after)."""
    from fviz.run.prestart import import_in_background

    import_in_background("pyarrow.parquet", "rerun", "rerun.blueprint", "fviz.record.pair_recording", "rich.console", "rich.table")


def _widened(config: RunConfig, out_dir: Path, resume: bool) -> RunConfig:
    """On --resume, the run's estimators stay (results are per pair and estimator): those asked for
    that it lacks are added, with a note when some were not asked for."""
    old = read_config(out_dir) if resume else None
    if old is None or old.comparable() != config.comparable():
        return config
    names = config.options.names
    kept = tuple(n for n in old.options.names if n not in names)
    if not kept:
        return config
    print(f"note: --resume keeps the run's other estimators ({', '.join(kept)}): results are per pair and estimator, "
          "only the missing ones are computed", file=sys.stderr)
    return replace(config, options=replace(config.options, names=old.options.names + tuple(n for n in names if n not in old.options.names)),
                   baseline_F={**old.baseline_F, **config.baseline_F})


def _todo(config: RunConfig, store: ResultStore, pairs: list[tuple[int, PairId]], out_dir: Path
          ) -> tuple[list[tuple[int, PairId]], dict[str, tuple[str, ...]], dict[str, Any]]:
    """(pairs to evaluate, pair name -> the estimators it lacks where it has a record with a result,
    pair name -> that record's Entry). A --full pair whose payload is missing or not the size its record
    says is evaluated again, and whole (its payload holds every estimator's inliers)."""
    names = config.estimator_names()
    latest = store.latest()
    todo, only, partial = [], {}, {}
    for i, pid in pairs:
        entry = latest.get(pid.name)
        if entry is not None and config.full and entry.has_result and not _payload_intact(payload_path(out_dir, i), entry):
            entry = None
        missing = tuple(n for n in names if entry is None or n not in entry.estimators)
        if not missing:
            continue
        todo.append((i, pid))
        if entry is not None and entry.has_result and len(missing) < len(names) and not config.full:
            only[pid.name], partial[pid.name] = missing, entry
    return todo, only, partial


def _payload_intact(path: Path, entry) -> bool:
    """Whether a --full payload is there and as long as when it was written (read only by the reports)."""
    try:
        size = path.stat().st_size
    except OSError:
        return False
    return entry.payload_bytes is None or size == entry.payload_bytes


def _run(config: RunConfig, out_dir: Path, pool: WorkerPool | None, resume: bool, progress: bool) -> RunOutcome:
    config = prepare(_widened(config, out_dir, resume))
    _check_resume(out_dir, config, resume)
    pairs = config.pairs()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FvizError(f"--out-dir {out_dir}: cannot create it ({exc.strerror})") from None
    store = ResultStore(out_dir, config)
    store.check_writable()
    todo, only, partial = _todo(config, store, pairs, out_dir)
    write_config(out_dir, config)
    outcome = RunOutcome(total=len(pairs), reused=len(pairs) - len(todo), computed=0, interrupted=False, out_dir=out_dir)

    def on_record(rec: dict) -> None:
        writer.add(rec.pop(CACHE_FRESH, []))
        outcome.cache_notes.update(rec.pop(CACHE_NOTES, {}))
        outcome.cached_features += rec.get("cached_features", 0)
        if rec["key"] in partial:
            rec = merge_record(next(read_records([partial[rec["key"]]])), rec, config.estimator_names())
        store.append(rec)
        outcome.computed += 1
        outcome.failed += rec["error"] is not None
        outcome.detections += rec["detections"]
        bar.advance()

    def on_started() -> None:  # the workers are busy: what this process imports now delays no pair
        bar.show()
        _preload_reports()

    writer = CacheWriter(out_dir)
    with Interrupts() as interrupts:
        with _Progress(progress, len(pairs), outcome.reused) as bar:
            try:
                _execute(config, todo, pool, out_dir, on_record, interrupts, only, on_started)
            except KeyboardInterrupt:
                pass
            except WriteError as exc:
                raise WriteError(f"{exc}; the pairs recorded before are kept: free some space, then finish with: "
                                 f"fviz eval --out-dir {out_dir} --resume") from None
            finally:
                store.close()
                outcome.cache_notes.update(dict.fromkeys(writer.close(), 1))
        interrupts.stage, interrupts.raise_from = "reports", 2
        outcome.paths = write_reports(out_dir, config)
        outcome.interrupted = interrupts.count > 0
    return outcome


# ------------------------------------------------------------------------------ reports
