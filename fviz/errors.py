"""The one error type users see: a one-line message naming the file or field at fault."""

import contextlib
import contextvars


class FvizError(Exception):
    """A usage or data error. The CLI prints ``error: <message>`` and exits with code 2."""

    exit_code = 2


class Interrupted(FvizError):
    """Ctrl-C (or SIGTERM) stopped a command; the message says what was kept. Exit code 130."""

    exit_code = 130


# Who called: the command line names its flags in errors ("--frames 0:9: ..."), Python the parameters
# ("frames 0:9: ..."): fviz.api renames the flag that starts a message unless the command line is the caller.
_COMMAND_LINE = contextvars.ContextVar("fviz_command_line", default=False)


@contextlib.contextmanager
def command_line():
    """Within it, errors name the command line's flags (the ``fviz`` commands run inside it)."""
    token = _COMMAND_LINE.set(True)
    try:
        yield
    finally:
        _COMMAND_LINE.reset(token)


def from_command_line() -> bool:
    """Whether the caller is the ``fviz`` command line (:func:`command_line`)."""
    return _COMMAND_LINE.get()


_noted: set[str] = set()  # notes said once per process


def note_once(message: str) -> None:
    """Print ``message`` on stderr, once per process (a source's note, however many pairs it loads)."""
    import sys

    if message not in _noted:
        _noted.add(message)
        print(message, file=sys.stderr)
