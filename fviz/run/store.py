"""What a run keeps on disk: run.json, results.jsonl (append-only, the source of truth) and the
optional per-pair payloads of ``--full``; records back to PairResult objects and CSV rows."""

from __future__ import annotations

import contextlib
import json
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from fviz.atomic import os_error, replacing, write_text
from fviz.errors import FvizError
from fviz.evaluate import EstimatorResult, PairResult
from fviz.run.config import PAYLOAD_DIR, RESULTS_FILE, RUN_FILE, RunConfig



def payload_path(out_dir: Path, index: int) -> Path:
    return Path(out_dir) / PAYLOAD_DIR / f"{index:06d}.npz"


def save_payload(path: Path, result: PairResult) -> None:
    """The arrays log_pair needs beyond the JSON record (atomic: temporary name, then rename)."""
    arrays = {"x_a": result.matches.x_a, "x_b": result.matches.x_b, "eval_mask": result.eval_mask}
    for i, r in enumerate(result.estimators):
        if r.inliers is not None:
            arrays[f"inliers_{i}"], arrays[f"residuals_{i}"] = r.inliers, r.residuals_px
    with replacing(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)


def load_payload(path: Path, result: PairResult) -> PairResult:
    """Fill matches, the evaluation mask, inliers and residuals of a result rebuilt from its record."""
    from fviz.estimators.features import Matches

    with np.load(path) as z:
        n = len(z["x_a"])
        result.matches = Matches(np.zeros((n, 2), int), z["x_a"], z["x_b"], np.zeros(n))
        result.eval_mask = z["eval_mask"]
        for i, r in enumerate(result.estimators):
            if f"inliers_{i}" in z:
                r.inliers, r.residuals_px = z[f"inliers_{i}"], z[f"residuals_{i}"]
    return result


# ------------------------------------------------------------------------------ records


def _float(v) -> float:
    return float("nan") if v is None else float(v)


def result_from_record(rec: dict[str, Any], config: RunConfig) -> PairResult:
    """The PairResult of a record (without matches): rebuilt from its JSON, or, for a pair that failed
    before evaluation, one error entry per estimator so rows and metric series stay aligned."""
    d = rec.get("result")
    if d is None:
        return PairResult(
            pair=rec["ref"], norm=config.norm, eval_threshold_px=config.eval_threshold, F_gt=np.full((3, 3), np.nan),
            n_keypoints=(0, 0), n_matches=0, n_eval=0, timings={},
            estimators=[EstimatorResult(n, None, {}, 0.0, rec["error"]) for n in config.series_names()],
        )
    array = lambda v: None if v is None else np.array(v)  # noqa: E731
    ests = [EstimatorResult(e["name"], array(e["F"]), {k: _float(v) for k, v in e["metrics"].items()}, e["seconds"],
                            e["error"], R=array(e.get("R")), t=array(e.get("t")))
            for e in d["estimators"]]
    return PairResult(
        pair=d["pair"], norm=d["norm"], eval_threshold_px=d["eval_threshold_px"], F_gt=None if d["F_gt"] is None else np.array(d["F_gt"]),
        n_keypoints=tuple(d["n_keypoints"]), n_matches=d["n_matches"], n_eval=d["n_eval"], timings=d["timings"],
        estimators=ests, notes=d.get("notes", []),
        match_precision={k: _float(v) for k, v in d.get("match_precision", {}).items()},
    )


def record_rows(rec: dict[str, Any], result: PairResult) -> list[dict[str, Any]]:
    """CSV rows of a record: PairResult.rows() with the pair's index first and its pair-level error."""
    return [{"index": rec["index"], **row, "pair_error": rec["error"] or ""} for row in result.rows()]


_CUT = object()
_RECORD_KEYS = {"key": str, "index": int, "estimators": list, "ref": dict}
_RESULT_KEYS = {"pair": dict, "norm": str, "eval_threshold_px": (int, float), "F_gt": (list, type(None)), "n_keypoints": list,
                "n_matches": int, "n_eval": int, "timings": dict, "estimators": list}
_ESTIMATOR_KEYS = {"name": str, "metrics": dict, "seconds": (int, float)}
_warned: set[str] = set()


def _type_problem(d: dict, keys: dict[str, Any], where: str) -> str | None:
    for key, kind in keys.items():
        if key not in d:
            return f"no '{where}{key}'"
        if not isinstance(d[key], kind) or isinstance(d[key], bool):
            return f"'{where}{key}' is {type(d[key]).__name__}"
    return None


def record_problem(rec: Any) -> str | None:
    """What keeps a parsed results.jsonl line from being a pair record, or None."""
    if not isinstance(rec, dict):
        return f"{type(rec).__name__}, not an object" if rec is not None else "null"
    problem = _type_problem(rec, _RECORD_KEYS, "")
    if problem:
        return problem
    if rec["index"] < 0 or not all(isinstance(n, str) for n in rec["estimators"]):
        return "bad 'index' or 'estimators'"
    result, error = rec.get("result"), rec.get("error")
    if error is not None and not isinstance(error, str):
        return f"'error' is {type(error).__name__}"
    if result is None:
        return None if error else "neither 'result' nor 'error'"
    if not isinstance(result, dict):
        return f"'result' is {type(result).__name__}"
    problem = _type_problem(result, _RESULT_KEYS, "result.")
    if problem:
        return problem
    for e in result["estimators"]:
        problem = _type_problem(e, _ESTIMATOR_KEYS, "result.estimators[].") if isinstance(e, dict) else "an estimator is not an object"
        if problem or "F" not in e or "error" not in e:
            return problem or "no 'result.estimators[].F' or '.error'"
    return None


def _warn_once(message: str) -> None:
    if message not in _warned:
        _warned.add(message)
        print(message, file=sys.stderr)


class ResultStore:
    """results.jsonl: append-only, one record per line, flushed per pair."""

    def __init__(self, out_dir: Path):
        self.path = Path(out_dir) / RESULTS_FILE
        self._file = None

    def _scan(self) -> Iterator[tuple[int, dict[str, Any]]]:
        """(byte offset, record) of every complete, valid line. A line that is JSON but not a record
        (``null``, a missing key, a wrong type) is skipped with a warning: its pair counts as not done."""
        if not self.path.is_file():
            return
        with open(self.path, "rb") as f:
            offset = 0
            for number, line in enumerate(f, 1):
                if line.endswith(b"\n"):
                    try:
                        rec = json.loads(line)
                    except ValueError:
                        rec = _CUT  # a line cut by a crash (the append after it starts a new line)
                    problem = record_problem(rec) if rec is not _CUT else None
                    if problem:
                        _warn_once(f"warning: {self.path}:{number}: not a pair record ({problem}); skipped, "
                                   "its pair is evaluated again")
                    elif rec is not _CUT:
                        yield offset, rec
                offset += len(line)

    def latest(self) -> dict[str, tuple[int, int, tuple[str, ...]]]:
        """key -> (offset, index, estimator names) of each pair's last record."""
        return {rec["key"]: (off, rec["index"], tuple(rec["estimators"])) for off, rec in self._scan()}

    def records(self) -> Iterator[dict[str, Any]]:
        """Each pair's last record, by index, read one at a time."""
        yield from read_records([(self.path, off, index) for off, index, _ in self.latest().values()])

    def append(self, rec: dict[str, Any]) -> None:
        """Append one record (unbuffered: a failed write leaves nothing pending; a cut line is ignored)."""
        line = (json.dumps(rec, allow_nan=True) + "\n").encode()
        try:
            if self._file is None:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self._file = open(self.path, "ab", buffering=0)
                if self._file.tell() > 0 and not _ends_with_newline(self.path):
                    line = b"\n" + line  # a line cut by a crash stays an (ignored) line of its own
            view = memoryview(line)
            while view:
                view = view[self._file.write(view):]
        except OSError as exc:
            raise os_error(self.path, exc) from None

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def read_records(entries: list[tuple[Path, int, int]]) -> Iterator[dict[str, Any]]:
    """Records at (file, offset, index) entries, in index order, one at a time."""
    handles: dict[Path, Any] = {}
    try:
        for path, off, _ in sorted(entries, key=lambda e: e[2]):
            f = handles.get(path) or handles.setdefault(path, open(path, "rb"))
            f.seek(off)
            yield json.loads(f.readline())
    finally:
        for f in handles.values():
            f.close()


def _ends_with_newline(path: Path) -> bool:
    with open(path, "rb") as f:
        f.seek(-1, os.SEEK_END)
        return f.read(1) == b"\n"


def read_config(out_dir: Path) -> RunConfig | None:
    path = Path(out_dir) / RUN_FILE
    if not path.is_file():
        return None
    try:
        return RunConfig.from_dict(json.loads(path.read_text()))
    except (ValueError, KeyError, TypeError) as exc:
        raise FvizError(f"{path}: not an fviz run configuration ({exc})") from None


def write_config(out_dir: Path, config: RunConfig) -> None:
    write_text(Path(out_dir) / RUN_FILE, json.dumps(config.to_dict(), indent=2))


# ------------------------------------------------------------------------------ lock

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


def _acquire(out_dir: Path) -> int:
    """A descriptor of ``out_dir/.fviz.lock`` holding an exclusive flock, the holder written into it."""
    import fcntl
    import shlex
    import socket
    import sys
    from datetime import datetime, timezone

    from fviz.atomic import describe_os_error

    path = out_dir / LOCK_FILE
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            raise FvizError(f"--out-dir {out_dir}: cannot lock it ({describe_os_error(exc)})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder_text(fd) or "another process"
            os.close(fd)
            raise FvizError(f"--out-dir {out_dir} is in use by {holder}: wait for it or choose another folder") from None
        try:
            if os.fstat(fd).st_ino == os.stat(path).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)  # the holder removed the file between our open and flock: lock the new one
    stale = _holder_text(fd)
    if stale:
        print(f"note: --out-dir {out_dir}: recovered the lock left by {stale}, which is no longer running",
              file=sys.stderr)
    holder = {"pid": os.getpid(), "host": socket.gethostname(), "command": shlex.join(["fviz", *sys.argv[1:]]),
              "since": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")}
    os.ftruncate(fd, 0)
    os.pwrite(fd, json.dumps(holder).encode(), 0)
    return fd


@contextlib.contextmanager
def locked(out_dir: str | Path) -> Iterator[None]:
    """Hold the run folder while eval, triage or merge writes into it (re-entrant within a process).

    Another fviz run into it exits with a one-line error naming the holder (pid, host, command, start
    time). The kernel releases the flock when the holder dies, however it dies: the next run takes over
    the lock file it left and says so."""
    from fviz.atomic import describe_os_error

    out_dir = Path(out_dir)
    created = not out_dir.exists()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FvizError(f"--out-dir {out_dir}: cannot create it ({describe_os_error(exc)})") from None
    key = out_dir.resolve()
    if key in _held:
        _held[key] += 1
        try:
            yield
        finally:
            _held[key] -= 1
        return
    fd = _acquire(out_dir)
    _held[key] = 1
    try:
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

@dataclass
class RunOutcome:
    total: int  # pairs of this run (its shard)
    reused: int  # already in results.jsonl
    computed: int  # evaluated now
    interrupted: bool
    out_dir: Path
    failed: int = 0
    detections: int = 0
    paths: dict[str, Path] = field(default_factory=dict)
