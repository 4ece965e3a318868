"""Nothing is lost: every file fviz writes goes to a temporary file beside its target and is renamed over
it only when complete. A symlink is written through (its target is replaced, the link stays), except one
planted in a run or train folder that points outside it (:func:`owning`: refused); a folder,
device node, FIFO or socket is never replaced (one-line :class:`FvizError`). On any failure or Ctrl-C the
temporary file is removed and the previous version stays; a full disk or a size limit becomes a one-line
error naming the file. The temporary file is made by ``tempfile.mkstemp`` in the target's folder (an
unpredictable name, created with O_EXCL: a planted symlink is never written through), and the file that
replaces another keeps its permissions (a new one gets the umask's).

    with replacing("runs/x.csv") as tmp:   # tmp: where to write; renamed onto the target on success
        tmp.write_text(...)
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from pathlib import Path
from typing import Iterator

from fviz.errors import FvizError

# errno -> what a user reads
_OS_ERRORS = {
    errno.ENOSPC: "disk full",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large for this system's limits",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "permission denied",
}


def describe_os_error(exc: OSError) -> str:
    """A short reason for ``exc`` ("disk full (No space left on device)")."""
    reason = exc.strerror or type(exc).__name__
    label = _OS_ERRORS.get(exc.errno)
    return f"{label} ({reason})" if label else reason


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


_OWNED: dict[Path, int] = {}  # folders fviz owns now (a run or train folder, resolved) -> nesting depth


@contextlib.contextmanager
def owning(folder: str | Path) -> Iterator[None]:
    """While inside, every file written into ``folder`` (or below) stays inside it: a symlink planted there that
    points outside is never written through (one-line FvizError), so a run never writes outside its folder."""
    key = Path(os.path.realpath(folder))
    _OWNED[key] = _OWNED.get(key, 0) + 1
    try:
        yield
    finally:
        _OWNED[key] -= 1
        if not _OWNED[key]:
            del _OWNED[key]


def _within(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _check_owned(path: Path, final: Path) -> None:
    """FvizError when ``path`` lies in a folder fviz owns now and its symlink chain ends outside that folder."""
    if not _OWNED or final == Path(os.path.abspath(path)):
        return
    where = Path(os.path.realpath(Path(os.path.abspath(path)).parent))
    for folder in _OWNED:
        if _within(where, folder) and not _within(final, folder):
            raise FvizError(f"{path} is a symlink to {final}, outside {folder}: fviz writes a run's files only inside "
                            "its folder (remove the link)")


def target(path: str | Path) -> Path:
    """The file that writing ``path`` replaces: ``path`` itself, or the end of its symlink chain (never outside a
    folder fviz owns now, :func:`owning`).

    Raises FvizError when that is anything but a regular file or a name not taken yet."""
    path = Path(path)
    final = Path(os.path.realpath(path))  # follows symlinks, dangling ones included
    _check_owned(path, final)
    try:
        mode = os.stat(final).st_mode
    except FileNotFoundError:
        return final
    except OSError as exc:
        raise FvizError(f"{path}: cannot write it: {describe_os_error(exc)}") from None
    if not stat.S_ISREG(mode):
        shown = path if final == path.absolute() else f"{path} (-> {final})"
        raise FvizError(f"{shown} is {_kind(mode)}, not a regular file: fviz only replaces regular files")
    return final


def tmp_path(path: str | Path) -> Path:
    """A new, empty temporary file beside ``path`` (hidden, an unpredictable name, mode 600 until commit)."""
    import tempfile

    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.tmp", dir=path.parent)
    os.close(fd)
    return Path(name)


def _mode_for(final: Path) -> int:
    """The permissions of the file ``final`` replaces, or those a new file gets under the umask."""
    try:
        return stat.S_IMODE(os.stat(final).st_mode)
    except OSError:
        mask = os.umask(0)
        os.umask(mask)
        return 0o666 & ~mask


def prepare(path: str | Path) -> tuple[Path, Path]:
    """(the file replaced, its temporary sibling, already created) for writing ``path``; creates the folder."""
    final = target(path)
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FvizError(f"{path}: cannot create its folder: {describe_os_error(exc)}") from None
    try:
        return final, tmp_path(final)
    except OSError as exc:
        raise os_error(path, exc) from None


def commit(path: str | Path, tmp: Path, final: Path) -> None:
    """Rename the complete ``tmp`` over ``final`` (checked again: still a regular file or nothing),
    with the permissions of the file it replaces."""
    try:
        target(path)
        os.chmod(tmp, _mode_for(final))
        os.replace(tmp, final)
    except BaseException as exc:
        _remove(tmp)
        if isinstance(exc, OSError):
            raise os_error(path, exc) from None
        raise


class WriteError(FvizError):
    """Writing a file failed (disk full, size limit, permissions); the previous version is kept."""


def os_error(path: str | Path, exc: OSError) -> WriteError:
    """The one-line error for an OSError while writing ``path``."""
    return WriteError(f"cannot write {path}: {describe_os_error(exc)}")


@contextlib.contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside the file ``path`` stands for; on success rename it over that file.

    On any exception (Ctrl-C included) the temporary file is removed and the previous file stays; an
    OSError (disk full, size limit, permissions) becomes a one-line FvizError naming ``path``."""
    final, tmp = prepare(path)
    try:
        yield tmp
    except BaseException as exc:
        _remove(tmp)
        if isinstance(exc, OSError):
            raise os_error(path, exc) from None
        raise
    commit(path, tmp, final)


def _remove(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.unlink()


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; returns ``path``."""
    with replacing(path) as tmp:
        tmp.write_text(text)
    return Path(path)
