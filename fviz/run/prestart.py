"""The worker processes of ``eval`` and ``triage``, started the moment the command is known (:mod:`fviz.entry`),
before the command line is imported and its options parsed (typer and its parsing, ~0.3 s) and the run is prepared:
their own imports (numpy, OpenCV, fviz's evaluation) overlap the main process's instead of following them. A run's
:class:`fviz.run.execute.WorkerPool` takes them (:func:`take`); a command that ends first (``--help``, a bad
flag, a run too small for workers) leaves them to die with it (they die with their parent).

Deliberately light: multiprocessing only. The workers import everything else themselves.
"""

from __future__ import annotations

import contextlib
import os

WORKER_PRELOAD = ("cv2", "numpy.random", "fviz.evaluate", "fviz.estimators.classical", "fviz.diagnose", "fviz.data.kitti",
                  "fviz.data.correspondences", "fviz.run.hloc_cache")
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
COMMANDS = ("eval", "triage")

_started: list[tuple] = []  # (process, connection) of workers started before a pool took them


def spawn_worker(preload: tuple[str, ...] = WORKER_PRELOAD, fork: bool = False) -> tuple:
    """(process, connection) of a new worker (:func:`fviz.run.worker.worker_main`): one BLAS/OpenMP thread,
    Ctrl-C and SIGTERM ignored (the main process's business), dying with this process. ``fork``: a fork of
    this process (no new interpreter to start), safe only while it has one thread and nothing heavy imported
    (:func:`prestart`); else a fresh interpreter (spawn)."""
    import multiprocessing as mp

    ctx = mp.get_context("fork" if fork else "spawn")
    parent, child = ctx.Pipe()
    inherited = (parent.fileno(), *(c.fileno() for _, c in _started)) if fork else ()  # other pipes' ends a fork holds
    proc = ctx.Process(target=_entry, args=(child, os.getpid(), preload, inherited), daemon=True, name="fviz-eval-worker")
    with _single_threaded_children(), _signals_ignored():
        proc.start()
    child.close()
    return proc, parent


def _entry(conn, parent_pid: int, preload: tuple[str, ...], inherited: tuple[int, ...] = ()) -> None:
    for fd in inherited:  # a fork's copies of the main process's ends: the pipes close when the main process's do
        with contextlib.suppress(OSError):
            os.close(fd)
    from fviz.run.worker import worker_main

    worker_main(conn, parent_pid, preload)


def command_of(argv: list[str]) -> str | None:
    """The fviz command in ``argv`` (after the root's own flags), None when there is none."""
    return next((a for a in argv if not a.startswith("-")), None)


def prestart(argv: list[str]) -> None:
    """Start one worker per core (at most ``--workers``) for an ``eval`` / ``triage`` command line; none for
    ``--help`` or one worker."""
    if command_of(argv) not in COMMANDS or "--help" in argv or _started:
        return
    workers = next((argv[i + 1] for i, a in enumerate(argv[:-1]) if a == "--workers"), None)
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if workers is not None and workers.isdigit():
        n = min(n, int(workers))
    if n <= 1:
        return
    _started.extend(spawn_worker(fork=_fork_safe()) for _ in range(n))


def _fork_safe() -> bool:
    """Whether workers may be forks of this process: Linux, one thread, and none of the libraries that
    keep threads or state a fork would copy (BLAS, OpenCV, torch) imported yet."""
    import sys
    import threading

    return sys.platform == "linux" and threading.active_count() == 1 and not {"numpy", "cv2", "torch"} & sys.modules.keys()


def take(n: int) -> list[tuple]:
    """Up to ``n`` of the workers started early; the others are ended."""
    taken = _started[:n]
    for proc, conn in _started[len(taken):]:
        with contextlib.suppress(OSError, ValueError):
            proc.kill()
            proc.join()
            conn.close()
    _started.clear()
    return taken


@contextlib.contextmanager
def _signals_ignored():
    """SIGINT and SIGTERM ignored while workers start (spawned processes inherit the disposition)."""
    import signal

    previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


@contextlib.contextmanager
def _single_threaded_children():
    """Worker processes inherit one BLAS/OpenMP thread each (one process per core already)."""
    saved = {k: os.environ.get(k) for k in THREAD_ENV}
    os.environ.update({k: "1" for k in THREAD_ENV})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v



def import_in_background(*modules: str) -> None:
    """Import ``modules`` in a thread while the caller works on. Not a daemon thread: an error that ends the
    command at once would otherwise finalise the interpreter while a native extension (rerun, pyarrow) is half
    imported, which crashes it (SIGSEGV or heap corruption after the error line, exit -11 instead of 2)."""
    import threading

    def run() -> None:
        for name in modules:
            with contextlib.suppress(Exception):
                __import__(name)

    threading.Thread(target=run, name="fviz-preload").start()
