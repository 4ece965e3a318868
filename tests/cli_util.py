"""Run the real ``fviz`` command line in a process of its own, as a user would: forked from a server that has
imported the heavy libraries once (tests/fork_server.py), or, with ``FVIZ_TEST_SUBPROCESS=1``, a fresh
``python -m fviz``."""

import atexit
import csv
import json
import os
import resource
import select
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path


# The smallest network a recipe can name (seconds to train on a CPU): the [model] table of test recipes.
TINY_MODEL_TOML = """[model]
variant = "siamese-rec-pos-fbn"
input_size = [32, 96]
width = 8
hidden = 16
pool_grid = [2, 4]
"""


def synthetic_recipe(path, out_dir, extra: str = ""):
    """A recipe training the tiny network on 8 synthetic pairs (4 held out), batches of 4, into ``out_dir``;
    ``extra``: more lines of its [train] table. -> path."""
    path.write_text(f"""{TINY_MODEL_TOML}[data]
source = "synthetic"
train_size = 8
val_size = 4
[train]
batch_size = 4
epochs = 5
num_workers = 0
out_dir = "{out_dir}"
{extra}""")
    return path


class _ForkServer:
    def __init__(self):
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).with_name("fork_server.py"))],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)
        self.lock = threading.Lock()
        self.pending = b""  # answers read from the pipe, not yet taken (both can arrive in one read)
        atexit.register(self.close)

    def close(self) -> None:
        """End the server (its stdin closes) and reap it, so that its children's CPU counts in this process's."""
        if self.proc.poll() is None:
            self.proc.stdin.close()
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def _answer(self, timeout=None) -> dict:
        """The server's next answer line; TimeoutError when none arrives in ``timeout`` s (None: wait)."""
        fd = self.proc.stdout.fileno()
        while b"\n" not in self.pending:
            if timeout is not None and not select.select([fd], [], [], timeout)[0]:
                raise TimeoutError
            data = os.read(fd, 4096)
            if not data:
                raise RuntimeError(f"the fork server ended (exit {self.proc.wait()})")
            self.pending += data
        line, self.pending = self.pending.split(b"\n", 1)
        return json.loads(line)

    def run(self, argv, cwd, timeout, env, file_size_limit) -> subprocess.CompletedProcess:
        with self.lock, tempfile.TemporaryDirectory(prefix="fviz-cli-") as tmp:
            out, err = Path(tmp, "stdout"), Path(tmp, "stderr")
            out.touch()
            err.touch()
            self.proc.stdin.write(json.dumps({"argv": ["fviz", *argv], "cwd": str(cwd or os.getcwd()), "env": env,
                                              "stdout": str(out), "stderr": str(err),
                                              "file_size_limit": file_size_limit}) + "\n")
            pid = self._answer()["pid"]
            try:
                code = self._answer(timeout)["returncode"]
            except TimeoutError:
                os.kill(pid, signal.SIGKILL)
                self._answer()
                raise subprocess.TimeoutExpired(argv, timeout, out.read_text(), err.read_text()) from None
            return subprocess.CompletedProcess(argv, code, out.read_text(), err.read_text())


_server: _ForkServer | None = None


def run_fviz(*args, cwd=None, timeout=600, env=None, file_size_limit=None):
    """``fviz ARGS`` in a process of its own (room for a loaded machine: importing torch alone can take a minute):
    ``env`` its whole environment (default this one's);
    ``file_size_limit``: bytes a file may grow to (past it a write fails with EFBIG, as on a full disk)."""
    global _server
    argv = [str(a) for a in args]
    env = dict(os.environ if env is None else env)
    if os.environ.get("FVIZ_TEST_SUBPROCESS") == "1":
        def limit():
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (file_size_limit,) * 2)

        return subprocess.run([sys.executable, "-m", "fviz", *argv], capture_output=True, text=True, cwd=cwd, env=env,
                              timeout=timeout, preexec_fn=None if file_size_limit is None else limit)
    if _server is None or _server.proc.poll() is not None:
        _server = _ForkServer()
    return _server.run(argv, cwd, timeout, env, file_size_limit)


def invoke(*args, check: bool = True):
    """``fviz ARGS`` in this process (Typer's runner): the result, its exit code asserted 0 with ``check``."""
    from typer.testing import CliRunner

    from fviz.cli import app

    r = CliRunner().invoke(app, [str(a) for a in args], catch_exceptions=False)
    assert not check or r.exit_code == 0, r.output
    return r


def assert_one_line_error(proc, code, *fragments):
    assert proc.returncode == code, proc.stderr
    err = proc.stderr.strip().splitlines()
    assert "Traceback" not in proc.stderr
    assert len(err) == 1 and err[0].startswith("error: "), proc.stderr
    for f in fragments:
        assert f in err[0], err[0]


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
