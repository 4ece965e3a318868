"""A run's pairs from Python: one pair of a run folder read back on demand, as the run evaluated it (no other pair is
evaluated again), and two runs on one pair as one result. ``fviz open RUN --pair X [--versus RUN_B]`` is a client::

    pair, result = fviz.read_pair("runs/a", 3)                  # or the pair's name; result as fviz.inspect_pair's
    fviz.save_recording("pair3.rrd", pair, result)              # clickable, and editable: fviz.edit(pair, result)
    pair, both = fviz.read_pair("runs/a", 3, versus="runs/b")   # F's "a-magsac", "b-magsac", ...: one click, both runs

Bad input raises :class:`fviz.errors.FvizError` with a one-line message that starts with the parameter's name.

fviz's page draws a recording's pairs on demand from the run(s) behind it (:func:`run_of_recording`): a run's eval.rrd
(:class:`RunPairs`: the pair its time cursor reaches) and a compare.rrd (:class:`ComparedPairs`: the pair whose point
of the chart is clicked).
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

from fviz.api.names import python_errors
from fviz.api.pairs import Inspected, judged, pair_fingerprint
from fviz.api.runs import Run, _folder
from fviz.errors import FvizError, from_command_line

if TYPE_CHECKING:  # pragma: no cover
    from fviz.data.pair import Pair
    from fviz.evaluate import PairResult
    from fviz.run.config import RunConfig
    from fviz.run.reopen import Reopened

__all__ = ["read_pair"]

_UNSAFE = re.compile(r"[^A-Za-z0-9_.+-]+")  # what a run's label (a part of an F's name and of a file's) may not hold


def _config(folder: Path, where: str) -> RunConfig:
    from fviz.run import read_config

    config = read_config(folder)
    if config is None:
        raise FvizError(f"{where} {folder}: no run there ({'no run.json' if folder.is_dir() else 'no such folder'})")
    return config


def _reopened(run: Run | str | os.PathLike, pair: int | str, what: str, where: str) -> Reopened:
    from fviz.run.reopen import reopen

    if isinstance(pair, bool) or not isinstance(pair, (int, str)) or (isinstance(pair, int) and pair < 0):
        raise FvizError(f"{what} {pair!r}: expected a pair's index (an int >= 0) or its name")
    return reopen(_folder(run), _config(_folder(run), where), pair, what)


def _inspected(r: Reopened, ests: list | None = None, specs: dict | None = None) -> Inspected:
    """How the run evaluated the pair, as :func:`fviz.inspect_pair` keeps it (what :func:`fviz.reestimate` needs)."""
    c = r.config
    return Inspected(r.ests if ests is None else ests, r.specs if specs is None else specs, c.options, c.norm,
                     c.eval_threshold, c.options.threshold, c.estimator_timeout, [])


def run_labels(a, b, labels: Sequence[str] | None = None) -> tuple[str, str]:
    """Two runs' labels: ``labels``, else their folders' names (made safe in an F's name), or "a" and "b" when these
    agree."""
    if labels is None:
        la, lb = (_UNSAFE.sub("_", _folder(r).absolute().name) or "run" for r in (a, b))
        return (la, lb) if la != lb else ("a", "b")
    names = (labels,) if isinstance(labels, str) else tuple(labels)
    if len(names) != 2 or names[0] == names[1] or not all(isinstance(n, str) and n and not _UNSAFE.search(n) for n in names):
        raise FvizError(f"labels {labels!r}: two different names of letters, digits, '_', '.', '+', '-'")
    return names


@python_errors
def read_pair(run: Run | str | os.PathLike, pair: int | str, *, versus: Run | str | os.PathLike | None = None,
              labels: Sequence[str] | None = None) -> tuple[Pair, PairResult]:
    """One pair of a run folder, rebuilt on demand: the pair from the run's source (run.json), its matches from the
    run's cache (features.h5 / matches.h5; else computed again with the run's feature settings, with a note), and the
    run's estimators run again with the run's settings, so that its F's are those results.jsonl holds (a note names
    any that is not).

    Args:
        run: a :class:`fviz.Run` or its folder.
        pair: the pair's index on the run's ``pair`` timeline (results.jsonl's ``index``; eval.rrd's time) or its
            name (results.jsonl's ``key``; its end after a "/" is enough when unique).
        versus: another run (checkpoint, matcher, settings) on the same pair, found there by its name: one result
            holding both runs' F's.
        labels: with ``versus``, the two runs' labels (default: their folders' names, or "a" and "b").

    Returns:
        (:class:`fviz.Pair`, :class:`fviz.PairResult`) as :func:`fviz.inspect_pair` gives them: log it
        (:func:`fviz.log_result`, ``index=`` the pair's), save it, edit it (:func:`fviz.edit`). With ``versus`` the
        F's are named "<label>-<estimator>" (the ground truth once), each with its own run's metrics, drawn on the
        first run's matches (a note says where the runs' matches or settings differ).
    """
    names = None if versus is None else run_labels(run, versus, labels)  # checked before any work
    a = _reopened(run, pair, "--pair" if from_command_line() else "pair", "run")
    if versus is None:
        return a.pair, judged(a.pair, _inspected(a), a.result)
    b = _reopened(versus, a.record["key"], "--versus", "--versus")  # python_errors names the parameter
    return _both(a, b, names, _folder(versus))


def _both(a: Reopened, b: Reopened, labels: tuple[str, str], folder_b: Path) -> tuple[Pair, PairResult]:
    """Two runs' evaluations of one pair as one result (:func:`fviz.run.reopen.versus`), judged; FvizError when run b's
    pair of that name is another pair."""
    from fviz.run.reopen import versus as both

    if pair_fingerprint(a.pair) != pair_fingerprint(b.pair):
        raise FvizError(f"--versus {folder_b}: its pair {a.record['key']} has other pixels or another ground truth "
                        "than the first run's: not the same pair")
    result, ests, specs = both(a, b, labels)
    return a.pair, judged(a.pair, _inspected(a, ests, specs), result)


@python_errors
def pair_recording(run: Run | str | os.PathLike, pair: int | str, *, versus: Run | str | os.PathLike | None = None,
                   labels: Sequence[str] | None = None) -> tuple[Path, Pair, PairResult]:
    """:func:`read_pair`, written as inspect's recording into the run folder: RUN/pairs/<name>.rrd (with ``versus``:
    <name>.vs-<its label>.rrd). -> (the recording, the pair, its result)."""
    from fviz.api.pairs import save_recording
    from fviz.run.config import PAYLOAD_DIR

    p, result = read_pair(run, pair, versus=versus, labels=labels)
    tail = "" if versus is None else ".vs-" + run_labels(run, versus, labels)[1]
    folder = _folder(run) / PAYLOAD_DIR
    folder.mkdir(exist_ok=True)
    return save_recording(folder / f"{p.id.name.replace('/', '_')}{tail}.rrd", p, result), p, result


class RunPairs:
    """The pairs of the run whose eval.rrd fviz's page shows, read on demand (as :func:`read_pair` reads them) when
    the page's time cursor reaches one (:class:`fviz.interactive.OnDemand`): one at a time, with one evaluator (a
    network loads once). ``indices``: the pairs the run evaluated (their place on the ``pair`` timeline)."""

    hint = "right-click a plot (or move the time cursor) to draw that pair"

    def __init__(self, out_dir: Path):
        import threading

        from fviz.run.store import ResultStore

        self.out_dir, self.config = Path(out_dir), _config(Path(out_dir), "run")
        self.indices = sorted(e.index for e in ResultStore(self.out_dir, self.config).latest().values() if e.has_result)
        self._evaluator = None  # made on the first pair read (its estimators resolved once)
        self._lock = threading.Lock()  # pages are answered on a pool of threads; an evaluator is one pair at a time

    def reopened(self, which: int | str) -> Reopened:
        """Pair ``which`` (index or name) evaluated again as the run did (:func:`fviz.run.reopen.reopen`)."""
        from fviz.run.evaluator import PairEvaluator
        from fviz.run.reopen import reopen

        with self._lock:
            self._evaluator = self._evaluator or PairEvaluator(self.config, self.out_dir)
            return reopen(self.out_dir, self.config, which, evaluator=self._evaluator)

    def load(self, index: int) -> tuple[Pair, PairResult]:
        r = self.reopened(index)
        return r.pair, judged(r.pair, _inspected(r), r.result)

    def pick(self, entity_path, instance_id=None, position=None, view_name=None) -> int | None:
        """No selection picks a pair of eval.rrd: its plots move the time cursor (a right-click)."""
        return None

    def blueprint(self, sizes, names=()):
        """The run's layout as ``eval --full`` stores it, its views framing images of ``sizes``."""
        from fviz.record.rebuild import recording_blueprint
        from fviz.run.config import RRD_FILE

        return recording_blueprint(self.out_dir / RRD_FILE, sizes=sizes)[1]


class ComparedPairs:
    """The pairs a compare.rrd plots (``chart``: :func:`fviz.record.compare_plot.read_chart`), read on demand from the
    run(s) compared when fviz's page gets a click on a pair's point: as :func:`read_pair` reads them, with the second
    run's F's (``versus``) when two runs were compared. ``indices``: the pairs' places in the first run."""

    hint = "click a pair's point in the chart to draw that pair below it"

    def __init__(self, chart):
        a, b = chart.runs
        self.chart, self.a = chart, RunPairs(a)
        self.b = RunPairs(b) if Path(b).resolve() != Path(a).resolve() else None
        self.labels = run_labels(a, b) if self.b is not None else None
        self.names = dict(zip(chart.index, chart.names))
        self.indices = sorted(self.names)

    def load(self, index: int) -> tuple[Pair, PairResult]:
        a = self.a.reopened(self.names[index])
        if self.b is None:
            return a.pair, judged(a.pair, _inspected(a), a.result)
        return _both(a, self.b.reopened(a.record["key"]), self.labels, self.b.out_dir)

    def pick(self, entity_path, instance_id=None, position=None, view_name=None) -> int | None:
        """A selection on the chart -> the index of the pair clicked, None elsewhere (:meth:`Chart.pair_at`)."""
        k = self.chart.pair_at(entity_path, instance_id, position, view_name)
        return None if k is None else self.chart.index[k]

    def blueprint(self, sizes, names=()):
        """The chart above the pair's images (F's ``names``)."""
        from fviz.record.compare_plot import compare_blueprint

        return compare_blueprint(self.chart.title, sizes, names)


def run_of_recording(path: str | os.PathLike) -> RunPairs | ComparedPairs | None:
    """The pairs behind a recording that fviz's page draws on demand: the run whose eval.rrd ``path`` is (run.json
    beside it), the run(s) a compare.rrd compared (a warning when they are gone); None for any other recording."""
    import sys

    from fviz.record.compare_plot import read_chart
    from fviz.run.config import RRD_FILE, RUN_FILE

    path = Path(path)
    if path.name == RRD_FILE and (path.parent / RUN_FILE).is_file():
        return RunPairs(path.parent)
    chart = read_chart(path)
    if chart is None:
        return None
    try:
        return ComparedPairs(chart)
    except FvizError as exc:
        print(f"warning: {path}: a click on a pair draws nothing: {exc}", file=sys.stderr)
        return None
