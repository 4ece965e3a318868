"""A fork server for the CLI tests: one process per test worker imports numpy, OpenCV, rerun, torch, h5py and
fviz once (~1.5 s of CPU that every ``python -m fviz`` pays again, ~3.5 s more where it renders synthetic pairs or
trains: torch), then forks a child per command line (importing torch starts no thread: a fork is safe). The child is a
process of its own, as a user's would be: its cwd, environment, stdin (/dev/null), stdout and stderr (files,
file descriptors 1 and 2: native libraries' lines included), exit code and signals; it runs
:func:`fviz.entry.main` and exits through Python's exit handlers.

Protocol (one JSON object a line): the test worker writes ``{argv, cwd, env, stdout, stderr}`` and optionally
``file_size_limit`` (bytes: RLIMIT_FSIZE with SIGXFSZ ignored, so that a write past it fails as on a full disk);
the child puts the entries of its ``PYTHONPATH`` first on ``sys.path``, as a fresh interpreter would. The server answers
``{"pid": N}`` when the child started, then ``{"returncode": R}`` (negative: killed by that signal).
Run as a script; it ends when its stdin closes (the test worker ended)."""

from __future__ import annotations

import importlib
import json
import os
import resource
import signal
import sys

PRELOAD = ("numpy", "cv2", "rerun", "torch", "h5py", "fviz.cli", "fviz.entry", "fviz.api", "fviz.evaluate",
           "fviz.record.pair_recording", "fviz.run.execute", "fviz.diagnose", "fviz.estimators.classical", "fviz.compare",
           "fviz.viewer", "fviz.data.synthetic", "fviz.train.loop", "fviz.models.model")


def _child(req: dict, channel: int) -> None:
    code = 1
    try:
        os.close(channel)
        os.chdir(req["cwd"])
        os.environ.clear()
        os.environ.update(req["env"])
        for fd, path, flags in ((0, os.devnull, os.O_RDONLY), (1, req["stdout"], os.O_WRONLY | os.O_TRUNC),
                                (2, req["stderr"], os.O_WRONLY | os.O_TRUNC)):
            new = os.open(path, flags)
            os.dup2(new, fd)
            os.close(new)
        sys.argv = req["argv"]
        sys.path[:0] = [p for p in map(os.path.abspath, filter(None, req["env"].get("PYTHONPATH", "").split(os.pathsep)))
                        if p not in sys.path]
        importlib.invalidate_caches()  # modules a test wrote after the server looked at their folder
        if req.get("file_size_limit") is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (req["file_size_limit"],) * 2)
        code = 0
        try:
            from fviz.entry import main

            main()
        except SystemExit as exc:
            if exc.code is None:
                code = 0
            elif isinstance(exc.code, int):
                code = exc.code
            else:
                print(exc.code, file=sys.stderr)
                code = 1
        except BaseException:  # what a fresh interpreter does with an uncaught exception
            import traceback

            traceback.print_exc()
            code = 1
        import atexit

        atexit._run_exitfuncs()
        sys.stdout.flush()
        sys.stderr.flush()
    finally:
        os._exit(code)


def serve() -> None:
    for name in PRELOAD:
        __import__(name)
    channel = os.dup(1)
    out = os.fdopen(channel, "w", buffering=1)
    for line in sys.stdin:
        req = json.loads(line)
        pid = os.fork()
        if pid == 0:
            _child(req, channel)
        out.write(json.dumps({"pid": pid}) + "\n")
        _, status = os.waitpid(pid, 0)
        out.write(json.dumps({"returncode": os.waitstatus_to_exitcode(status)}) + "\n")


if __name__ == "__main__":
    serve()
