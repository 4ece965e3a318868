"""Write results to a Rerun recording, atomically: a temporary name, then a rename on success.

A crash never leaves a truncated file under the final name. ``eval`` keeps what it has on Ctrl-C by
closing the writer normally (the partial recording is valid and complete up to the last pair).

Runs end with Rerun's footer (an index of every chunk, for seeking in large files). A single pair's
recording does without it (it was 150 of 470 KB, and the viewer reads such a file whole); its last message
is ``layout.END`` instead, which tells a complete file from one cut between two messages.
"""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path

import numpy as np

from fviz.errors import FvizError
from fviz.record import layout as L

FLUSH_PAIRS = 50  # a run's recording is flushed every this many pairs (see RecordingWriter.pair_done)
JPEG_QUALITY = 50  # a KITTI frame in ~46 KB; zoomed 1.5x, no difference from 95 that a reader sees


def batching():
    """Rerun's batcher flushing only when told (a run every FLUSH_PAIRS pairs, or the end) or past 64 MB: its
    default flushes every 200 ms, so a loaded machine cut one pair's recording into more chunks (each with
    its own schema: 240 to 252 KB for the same pair). The same data now gives the same file."""
    import rerun as rr

    cfg = rr.ChunkBatcherConfig.NEVER()
    cfg.flush_num_bytes = 64 << 20
    cfg.chunk_max_rows_if_unsorted = 8192  # Rerun's default (NEVER's 256 would split triage's unsorted pairs)
    return cfg


class RecordingWriter:
    """``with RecordingWriter(path, app_id) as w: w.rec.log(...)``; the file appears only when complete.

    Written through :mod:`fviz.atomic` (a symlink's target is replaced, special files never). Rerun's file
    sink writes into a pipe that a thread copies to the temporary file: a full disk or a size limit then
    raises here, where a sink writing the file itself stops with a log line and its flush never returns.
    Any exception (Ctrl-C included) discards the temporary file and leaves the previous version in place.
    ``index``: end the file with Rerun's footer (runs); without it (a single pair) the last message is
    ``layout.END`` (see the module docstring).
    """

    def __init__(self, path: str | Path, app_id: str = "fviz", blueprint=None, index: bool = True, recording_id: str | None = None):
        import threading

        import rerun as rr

        from fviz import atomic

        self.path = Path(path)
        self._final, self.tmp = atomic.prepare(self.path)
        try:
            self._file = open(self.tmp, "wb")
        except OSError as exc:
            raise atomic.os_error(self.path, exc) from None
        self._error: OSError | None = None
        self._pairs = 0
        read_fd, self._write_fd = os.pipe()
        self._pump = threading.Thread(target=self._copy, args=(read_fd,), name="rrd-writer", daemon=True)
        self._pump.start()
        self.rec = rr.RecordingStream(app_id, recording_id=recording_id, batcher_config=batching())
        self.rec.set_log_time_enabled(False)  # deterministic files: only the ``pair`` timeline
        self.index = index
        try:
            with _stderr_silenced(not index):  # Rerun warns that a file without its index is slower to seek
                self.rec.save(f"/dev/fd/{self._write_fd}", default_blueprint=blueprint, write_footer=index)
        except Exception as exc:
            self._finish()
            self.tmp.unlink(missing_ok=True)
            raise FvizError(f"cannot write {self.path}: {exc}") from None

    def pair_done(self) -> None:
        """Call after each pair of a run. Rerun's stream keeps what it was given until a flush (eval.rrd
        grew the process by ~60 KB per pair without one): every FLUSH_PAIRS pairs it is flushed."""
        self._pairs += 1
        if self._pairs % FLUSH_PAIRS == 0:
            self.rec.flush()

    def _copy(self, read_fd: int) -> None:
        """Pipe -> temporary file; after a write error the pipe is still drained (the sink never blocks)."""
        with open(read_fd, "rb", buffering=0) as pipe:
            while chunk := pipe.read(1 << 20):
                if self._error is None:
                    try:
                        self._file.write(chunk)
                    except OSError as exc:
                        self._error = exc

    def _finish(self) -> None:
        os.close(self._write_fd)  # the sink's own descriptor closes on disconnect: then the pump sees EOF
        self._pump.join()
        try:
            self._file.close()
        except OSError as exc:
            self._error = self._error or exc

    def close(self, commit: bool = True) -> None:
        try:
            if commit and not self.index:
                import rerun as rr

                self.rec.flush()  # what was logged goes out first: the end mark is the file's last message
                self.rec.log(L.END, rr.TextDocument("complete"), static=True)
            self.rec.flush()
            self.rec.disconnect()
        finally:
            self._finish()
        from fviz import atomic

        if commit and self._error is None:
            atomic.commit(self.path, self.tmp, self._final)
            return
        self.tmp.unlink(missing_ok=True)
        if commit:
            raise atomic.os_error(self.path, self._error)

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(commit=exc_type is None)


@contextlib.contextmanager
def _stderr_silenced(silence: bool):
    """File descriptor 2 to /dev/null for the block (a Rust library's warning, which Python cannot catch);
    nothing is done when ``silence`` is False or the process has no stderr."""
    saved = None
    if silence:
        with contextlib.suppress(OSError, ValueError):
            sys.stderr.flush()
            saved = os.dup(2)
    if saved is None:
        yield
        return
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 2)
    os.close(null)
    try:
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def encode_jpeg(image: np.ndarray) -> bytes:
    import cv2

    bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY, cv2.IMWRITE_JPEG_OPTIMIZE, 1])
    if not ok:
        raise FvizError("JPEG encoding failed")
    return buf.tobytes()
