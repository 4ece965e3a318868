"""What a run keeps on disk: run.json, results.jsonl (append-only, the source of truth) and the
optional per-pair payloads of ``--full``; records back to PairResult objects and CSV rows."""

from __future__ import annotations

import json
import os
import stat
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Optional, TypedDict

import numpy as np

from fviz.atomic import os_error, replacing, write_text
from fviz.errors import FvizError
from fviz.evaluate import EstimatorResult, PairResult
from fviz.run.config import PAYLOAD_DIR, RESULTS_FILE, RUN_FILE, RunConfig
from fviz.schema import Mismatch, Real, convert
from fviz.stats import number


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


def payload_ok(path: Path) -> bool:
    """Whether a --full payload can be read back (a truncated or foreign file cannot)."""
    try:
        with np.load(path) as z:
            return all(k in z.files for k in ("x_a", "x_b", "eval_mask")) and len(z["x_a"]) == len(z["eval_mask"])
    except Exception:  # BadZipFile, OSError, ValueError, EOFError, pickled objects refused ...
        return False


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
    ests = [EstimatorResult(e["name"], array(e["F"]), {k: number(v) for k, v in e["metrics"].items()}, e["seconds"],
                            e["error"], R=array(e.get("R")), t=array(e.get("t")))
            for e in d["estimators"]]
    return PairResult(
        pair=d["pair"], norm=d["norm"], eval_threshold_px=d["eval_threshold_px"], F_gt=None if d["F_gt"] is None else np.array(d["F_gt"]),
        n_keypoints=tuple(d["n_keypoints"]), n_matches=d["n_matches"], n_eval=d["n_eval"], timings=d["timings"],
        estimators=ests, notes=d.get("notes", []),
        match_precision={k: number(v) for k, v in d.get("match_precision", {}).items()},
    )


def merge_record(old: dict[str, Any], new: dict[str, Any], order: list[str]) -> dict[str, Any]:
    """The record of a pair whose ``old`` record (with a result) lacked some estimators of ``order``
    (display names) and ``new`` computed them: old's estimators kept, new's added, in ``order``. A pair
    that failed as a whole now gets its error on the added estimators only."""
    from fviz.evaluate import GT_NAME

    res = old["result"]
    have = {e["name"]: e for e in res["estimators"]}
    got = {e["name"]: e for e in (new.get("result") or {}).get("estimators", [])}
    names = [n for n in order if n in have or n in got or n in new["estimators"]]
    names += [n for n in old["estimators"] if n not in names]
    failed = EstimatorResult("", None, {}, 0.0, f"pair failed when this estimator was added: {new['error']}").to_dict()
    gt = [have[GT_NAME]] if GT_NAME in have else []  # a pair without ground truth has no gt entry
    ests = gt + [have.get(n) or got.get(n) or {**failed, "name": n} for n in names]
    diag_old, diag_new = old.get("diagnostics"), new.get("diagnostics")
    diag = diag_old if not (diag_old and diag_new) else {
        **diag_old, "estimators": {**diag_new["estimators"], **diag_old["estimators"]}}
    return {**old, "estimators": names, "result": {**res, "estimators": ests}, "diagnostics": diag,
            "fingerprint": new["fingerprint"], "seconds": old.get("seconds", 0.0) + new.get("seconds", 0.0),
            **{k: new[k] for k in ("detections", "cached_features", "cached_matches", "finished_at", "worker") if k in new}}


def record_rows(rec: dict[str, Any], result: PairResult) -> list[dict[str, Any]]:
    """CSV rows of a record: PairResult.rows() with the pair's index first and its pair-level error."""
    return [{"index": rec["index"], **row, "pair_error": rec["error"] or ""} for row in result.rows()]


_CUT = object()
_warned: set[str] = set()


Row3 = tuple[float, float, float]
Matrix3 = tuple[Row3, Row3, Row3]  # F, R: finite


class _Estimator(TypedDict):
    name: str
    seconds: Real
    error: Optional[str]
    metrics: dict[str, Optional[Real]]


class EstimatorRecord(_Estimator, total=False):
    """One F of a record's result (:meth:`EstimatorResult.to_dict`); F, R, t finite when given."""

    F: Optional[Matrix3]
    R: Optional[Matrix3]
    t: Optional[Row3]


class PairSizes(TypedDict, total=False):
    size_a: tuple[int, int]  # [width, height]
    size_b: tuple[int, int]


class ResultRecord(TypedDict):
    """A record's ``result`` (:meth:`PairResult.to_dict`); its estimators are checked one by one."""

    pair: PairSizes
    norm: str
    eval_threshold_px: Real
    F_gt: Optional[Matrix3]
    n_keypoints: tuple[Real, Real]
    n_matches: int
    n_eval: int
    timings: dict[str, Real]
    estimators: list[dict]
    notes: list[str]


class DiagnosedEstimator(TypedDict, total=False):  # what triage reads
    n_inliers: Optional[Real]
    homography_fraction: Optional[Real]
    gt_agree: Optional[Real]
    gt_sed_median_inliers: Optional[Real]


class Diagnostics(TypedDict):
    n_matches: Real
    baseline_m: Real
    rotation_fraction: Optional[Real]
    estimators: dict[str, DiagnosedEstimator]


class _Record(TypedDict):
    key: str
    index: int
    estimators: list[str]
    ref: dict
    error: Optional[str]


class PairRecord(_Record, total=False):
    """One line of results.jsonl: the pair (``key``, its ``ref``), its result or its ``error``."""

    fingerprint: str
    diagnostics: Optional[Diagnostics]
    result: Optional[dict]


def _ref_problem(rec: dict) -> str | None:
    """Why ``ref`` does not name the pair ``key``, or None."""
    from dataclasses import fields

    from fviz.data.pair import PairId

    ref = rec["ref"]
    known = {f.name for f in fields(PairId)}
    try:
        pid = PairId(**{k: v for k, v in ref.items() if k in known})
        ok = pid.name == rec["key"]
        ints = all(isinstance(getattr(pid, f), int) and not isinstance(getattr(pid, f), bool)
                   for f in ("frame_a", "frame_b", "cam_a", "cam_b") if f in known)
        strs = all(isinstance(getattr(pid, f), str) for f in ("source", "sequence", "kind") if f in known)
    except (TypeError, ValueError) as exc:
        return f"'ref' is not a pair ({exc})"
    return None if ok and ints and strs else "'ref' does not name the pair of 'key'"


def _result_problem(rec: dict) -> str | None:
    result = rec["result"]
    convert(result, ResultRecord, "result")
    if any(result["pair"].get(k) != v for k, v in rec["ref"].items()):
        return "'result.pair' is not the pair of 'ref'"
    for e in result["estimators"]:
        convert(e, EstimatorRecord, "result.estimators[]")
    gt = ["gt"] if result["F_gt"] is not None else []  # a pair without ground truth has no gt row
    if [e["name"] for e in result["estimators"]] != gt + rec["estimators"]:
        return "'result.estimators' are not the record's 'estimators'"
    return None


def record_problem(rec: Any) -> str | None:
    """What keeps a parsed results.jsonl line from being a pair record (:class:`PairRecord`), or None: every field
    is checked (type, shape, finiteness; ``ref`` names the pair of ``key``; the result's estimators are the
    record's), so what reads records later (reports, resume, triage, eval.rrd) can trust them."""
    if not isinstance(rec, dict):
        return f"{type(rec).__name__}, not an object" if rec is not None else "null"
    try:
        convert(rec, PairRecord, "")
        if rec["index"] < 0:
            return f"'index' is {rec['index']}, expected >= 0"
        if (problem := _ref_problem(rec)) is not None:
            return problem
        if rec.get("result") is None:
            return None if rec["error"] else "neither 'result' nor 'error'"
        return _result_problem(rec)
    except Mismatch as exc:
        return exc.brief
    except FvizError as exc:
        return str(exc)


def _warn_once(message: str) -> None:
    if message not in _warned:
        _warned.add(message)
        print(message, file=sys.stderr)


@dataclass(frozen=True)
class Entry:
    """Where a pair's latest usable record is, and what it holds."""

    path: Path
    offset: int
    index: int  # the pair's place in the run's selection
    estimators: tuple[str, ...]
    has_result: bool  # False: the pair failed as a whole
    payload_bytes: int | None = None  # size of its --full payload when written


class ResultStore:
    """results.jsonl: append-only, one record per line, flushed per pair.

    Reading keeps only the records that belong to ``config`` (default: the run.json beside it): a pair of
    its selection, and a fingerprint (:meth:`RunConfig.fingerprint`) of its settings and that pair. Other
    records (another configuration, a pair outside the selection, no fingerprint) are ignored, with one
    warning that counts them."""

    def __init__(self, out_dir: Path, config: RunConfig | None = None):
        self.path = Path(out_dir) / RESULTS_FILE
        self._file = None
        self._config = config
        self._indices: dict[str, int] | None = None

    @property
    def config(self) -> RunConfig | None:
        if self._config is None:
            self._config = read_config(self.path.parent)
        return self._config

    def indices(self) -> dict[str, int] | None:
        """Pair name -> index in the whole selection of the configuration (None without one)."""
        if self._indices is None and self.config is not None:
            self._indices = {pid.name: i for i, pid in enumerate(self.config.selection.source().pair_ids())}
        return self._indices

    def check_writable(self) -> None:
        """A one-line error unless results.jsonl is a regular file (or absent): never a symlink, whose
        target the appends would grow."""
        try:
            mode = os.lstat(self.path).st_mode
        except FileNotFoundError:
            return
        if stat.S_ISLNK(mode):
            raise FvizError(f"{self.path} is a symlink: fviz appends records only to a regular file in the run folder "
                            "(replace the link by a copy of its target)")
        if not stat.S_ISREG(mode):
            raise FvizError(f"{self.path} is not a regular file")

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

    def latest(self) -> dict[str, Entry]:
        """key -> the Entry of each pair's last record that belongs to the configuration."""
        config, indices = self.config, self.indices()
        out: dict[str, Entry] = {}
        other = outside = 0
        for off, rec in self._scan():
            key = rec["key"]
            if indices is not None and key not in indices:
                outside += 1
                continue
            if config is not None and rec.get("fingerprint") != config.fingerprint(rec["ref"]):
                other += 1
                continue
            size = rec.get("payload_bytes")
            out[key] = Entry(self.path, off, indices[key] if indices else rec["index"], tuple(rec["estimators"]),
                             rec.get("result") is not None, size if isinstance(size, int) else None)
        if other or outside:
            parts = [f"{other} made with other settings or inputs (or without a fingerprint)"] * bool(other)
            parts += [f"{outside} of pairs outside the run's selection"] * bool(outside)
            _warn_once(f"warning: {self.path}: {other + outside} records ignored ({', '.join(parts)}); "
                       "only records of this run's pairs and settings are used")
        return out

    def records(self) -> Iterator[dict[str, Any]]:
        """Each pair's last usable record, by index, read one at a time."""
        yield from read_records(list(self.latest().values()))

    def append(self, rec: dict[str, Any]) -> None:
        """Append one record (unbuffered: a failed write leaves nothing pending; a cut line is ignored)."""
        line = (json.dumps(rec, allow_nan=True) + "\n").encode()
        try:
            if self._file is None:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.check_writable()
                fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o666)
                self._file = os.fdopen(fd, "ab", buffering=0)
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


def read_records(entries: list[Entry]) -> Iterator[dict[str, Any]]:
    """The records of ``entries``, in index order, one at a time (``index`` set to the entry's)."""
    handles: dict[Path, Any] = {}
    try:
        for e in sorted(entries, key=lambda e: e.index):
            f = handles.get(e.path) or handles.setdefault(e.path, open(e.path, "rb"))
            f.seek(e.offset)
            yield {**json.loads(f.readline()), "index": e.index}
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
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise FvizError(f"{path}: not an fviz run configuration ({getattr(exc, 'strerror', None) or exc})") from None
    try:
        return RunConfig.from_dict(doc)
    except FvizError as exc:  # a field of the wrong type or out of range, named
        raise FvizError(f"{path}: {exc}") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise FvizError(f"{path}: not an fviz run configuration ({exc})") from None


def write_config(out_dir: Path, config: RunConfig) -> None:
    write_text(Path(out_dir) / RUN_FILE, json.dumps(config.to_dict(), indent=2))


# ------------------------------------------------------------------------------ lock

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
    cached_features: int = 0  # images whose features came from the run folder's features.h5
    cache_notes: Counter = field(default_factory=Counter)  # why cache entries were ignored -> how many
