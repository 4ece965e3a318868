"""Native libraries' own lines on stderr (libpng's "libpng error: IDAT: CRC error") silenced while they
run, so that a bad input ends in fviz's one ``error:`` line alone.

The silence is process-wide (file descriptor 2) and reference-counted: threads decoding at once share one
window, and the real stderr comes back when the last one leaves."""

from __future__ import annotations

import contextlib
import os
import threading
from typing import Iterator

_lock = threading.Lock()
_depth = 0
_saved: int | None = None


@contextlib.contextmanager
def native_stderr_silenced() -> Iterator[None]:
    global _depth, _saved
    with _lock:
        if _depth == 0:
            try:
                _saved = os.dup(2)
                null = os.open(os.devnull, os.O_WRONLY)
                os.dup2(null, 2)
                os.close(null)
            except OSError:
                _saved = None
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0 and _saved is not None:
                os.dup2(_saved, 2)
                os.close(_saved)
                _saved = None
