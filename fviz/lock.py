"""A run folder's lock (``.fviz.lock``): an exclusive flock held while a command writes the folder, the holder's pid,
host, start and command written into it so that a second command names who holds it. Only a regular file is locked,
never through a symlink."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import stat
from pathlib import Path
from typing import Iterator

from fviz.errors import FvizError


LOCK_FILE = ".fviz.lock"


_held: dict[Path, int] = {}  # run folders this process holds -> nesting depth (triage runs eval inside)


def _holder_text(fd: int) -> str:
    """Who wrote the lock file: "pid P on HOST since T (COMMAND)", or "" when empty or unreadable."""
    os.lseek(fd, 0, os.SEEK_SET)
    try:
        h = json.loads(os.read(fd, 1 << 16) or b"null")
        return f"pid {h['pid']} on {h['host']} since {h['since']} ({h['command']})"
    except (ValueError, KeyError, TypeError):
        return ""


def open_lock_file(path: Path, flags: int, flag: str = "--out-dir") -> int:
    """A descriptor of the lock file ``path``, never through a symlink, and only of a regular file
    (a planted link or FIFO is refused: the holder's line is written into what is opened)."""
    from fviz.atomic import describe_os_error

    try:
        fd = os.open(path, flags | os.O_CLOEXEC | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
    except OSError as exc:
        why = "it is a symlink" if exc.errno == errno.ELOOP else describe_os_error(exc)
        raise FvizError(f"{flag} {path.parent}: cannot lock it ({path.name}: {why}; fviz locks only a regular file)") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise FvizError(f"{flag} {path.parent}: cannot lock it ({path.name} is not a regular file)")
    return fd


def _acquire(out_dir: Path, flag: str = "--out-dir") -> int:
    """A descriptor of ``out_dir/.fviz.lock`` holding an exclusive flock, the holder written into it."""
    import fcntl
    import shlex
    import socket
    import sys
    from datetime import datetime, timezone

    path = out_dir / LOCK_FILE
    while True:
        fd = open_lock_file(path, os.O_RDWR | os.O_CREAT, flag)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder_text(fd) or "another process"
            os.close(fd)
            raise FvizError(f"{flag} {out_dir} is in use by {holder}: wait for it or choose another folder") from None
        try:
            if os.fstat(fd).st_ino == os.stat(path).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)  # the holder removed the file between our open and flock: lock the new one
    stale = _holder_text(fd)
    if stale:
        print(f"note: {flag} {out_dir}: recovered the lock left by {stale}, which is no longer running",
              file=sys.stderr)
    holder = {"pid": os.getpid(), "host": socket.gethostname(), "command": shlex.join(["fviz", *sys.argv[1:]]),
              "since": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")}
    os.ftruncate(fd, 0)
    os.pwrite(fd, json.dumps(holder).encode(), 0)
    return fd


def holder_of(out_dir: Path) -> str | None:
    """Who holds ``out_dir``'s lock now ("pid ... (COMMAND)"), or None when nobody does (this process's
    own holds excepted)."""
    import fcntl

    path = Path(out_dir) / LOCK_FILE
    if Path(out_dir).resolve() in _held or not os.path.lexists(path):
        return None
    fd = open_lock_file(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return None
    except BlockingIOError:
        return _holder_text(fd) or "another process"
    finally:
        os.close(fd)


@contextlib.contextmanager
def locked(out_dir: str | Path, flag: str = "--out-dir") -> Iterator[None]:
    """Hold the run folder while eval, triage, merge or train writes into it (re-entrant within a process;
    ``flag`` names the folder in messages).

    Another fviz run into it exits with a one-line error naming the holder (pid, host, command, start
    time). The kernel releases the flock when the holder dies, however it dies: the next run takes over
    the lock file it left and says so."""
    from fviz.atomic import describe_os_error

    out_dir = Path(out_dir)
    created = not out_dir.exists()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FvizError(f"{flag} {out_dir}: cannot create it ({describe_os_error(exc)})") from None
    key = out_dir.resolve()
    if key in _held:
        _held[key] += 1
        try:
            yield
        finally:
            _held[key] -= 1
        return
    from fviz.atomic import owning

    fd = _acquire(out_dir, flag)
    _held[key] = 1
    try:
        with owning(out_dir):
            yield
    finally:
        del _held[key]
        with contextlib.suppress(OSError):
            os.unlink(out_dir / LOCK_FILE)  # still locked: a run starting now opens a new file
        os.close(fd)
        if created:  # a run that stopped before writing anything leaves no empty folder
            with contextlib.suppress(OSError):
                out_dir.rmdir()


# ------------------------------------------------------------------------------ execution
