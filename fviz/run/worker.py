"""A worker process of a run's pool (started by :mod:`fviz.run.prestart`): it dies with its parent, imports what
evaluation needs, builds its :class:`fviz.run.evaluator.PairEvaluator` from the configuration it is sent and
evaluates the tasks it is sent until it gets None."""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

DEEP_PRELOAD = ("torch", "fviz.models.predict", "fviz.train.checkpoint")


def die_with_parent(parent_pid: int) -> None:
    """Make this worker die with the process that started it (SIGKILL of the run included):
    PR_SET_PDEATHSIG on Linux, else a thread watching the parent's pid."""
    import signal

    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(1, signal.SIGKILL, 0, 0, 0) != 0:  # PR_SET_PDEATHSIG
            raise OSError(ctypes.get_errno(), "prctl")
    except (OSError, AttributeError):
        import threading

        def watch() -> None:
            while os.getppid() == parent_pid:
                time.sleep(0.5)
            os._exit(1)

        threading.Thread(target=watch, daemon=True, name="parent-watch").start()
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)


def worker_main(conn, parent_pid: int, preload: tuple[str, ...]) -> None:
    """A worker process: import what evaluation needs while the main process prepares the run, build its
    evaluator from the configuration it is then sent (once: estimators, a deep model), and evaluate
    the pairs it is sent until it gets None. Ctrl-C and SIGTERM are the main process's business."""
    import importlib
    import signal

    from fviz.run.config import RunConfig
    from fviz.run.evaluator import PairEvaluator, error_message

    die_with_parent(parent_pid)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    for name in preload:
        with contextlib.suppress(ImportError):
            importlib.import_module(name)
    import cv2

    cv2.setNumThreads(1)  # one process per core already
    try:
        message = conn.recv()
    except EOFError:
        return
    if message is None:
        return
    try:
        config_dict, out_dir, batched = message
        evaluator = PairEvaluator(RunConfig.from_dict(config_dict), Path(out_dir), detect_threads=1, batched=batched)
    except Exception as exc:
        conn.send(("failed", error_message(exc)))
        return
    conn.send(("ready", os.getpid()))
    while True:
        try:
            task = conn.recv()
        except EOFError:
            return
        if task is None:
            return
        try:
            result = evaluator.run_task(task)
        except Exception as exc:  # not a bad pair (those are records), e.g. a full disk: the run stops
            conn.send(("raised", exc))
            return
        conn.send(("done", result))
