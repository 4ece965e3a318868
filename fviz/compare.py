"""Compare two estimators pair by pair: wins, losses, ties, and the pairs where exactly one fails.

Sides come from the metrics.csv of ``fviz eval`` runs: two estimators of one run, or one estimator
of two runs (pairs matched by name). A side *fails* on a pair when the pair or the estimator errored,
the metric is NaN, or the metric is worse than ``fail_threshold`` (above it; below it for metrics
where higher is better). Wins and losses count the pairs where both sides have a value; a difference
within ``tie`` is a tie.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

from fviz.atomic import write_text
from fviz.errors import FvizError
from fviz.triage import HIGHER_IS_BETTER

COMPARE_FILE = "compare.md"
FAIL_THRESHOLD = 2.0  # px: sed_median above this is a failure (the paper's evaluation threshold)


@dataclass(frozen=True)
class Side:
    run: Path
    estimator: str

    @property
    def label(self) -> str:
        return f"{self.estimator} ({self.run})"


@dataclass
class Comparison:
    a: Side
    b: Side
    metric: str
    fail_threshold: float
    wins: list[str] = field(default_factory=list)  # a better
    losses: list[str] = field(default_factory=list)  # b better
    ties: list[str] = field(default_factory=list)
    only_a_fails: list[str] = field(default_factory=list)
    only_b_fails: list[str] = field(default_factory=list)
    both_fail: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)  # pairs of one side only
    values: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def names(self) -> tuple[str, str]:
        """How rows name the sides: the two estimators, or, for one estimator of two runs, it in each run."""
        if self.a.estimator != self.b.estimator:
            return self.a.estimator, self.b.estimator
        ra, rb = _distinct_tails(Path(self.a.run), Path(self.b.run))
        return f"{self.a.estimator} of {ra}", f"{self.b.estimator} of {rb}"


def _distinct_tails(a: Path, b: Path) -> tuple[str, str]:
    """The shortest trailing parts of two paths that tell them apart (runs/a, runs/b -> a, b)."""
    pa, pb = a.absolute().parts, b.absolute().parts
    for k in range(1, max(len(pa), len(pb)) + 1):
        ta, tb = "/".join(pa[-k:]), "/".join(pb[-k:])
        if ta != tb:
            return ta, tb
    return str(a), str(b)


def read_side(side: Side, metric: str) -> dict[str, tuple[float, str]]:
    """pair name -> (metric value or NaN, error message or "") of one estimator in a run's metrics.csv."""
    from fviz.run.config import check_metric_column, csv_number

    check_metric_column(metric)
    path = Path(side.run) / "metrics.csv"
    if not path.is_file():
        raise FvizError(f"{side.run}: no metrics.csv (run fviz eval --out-dir {side.run} first)")
    out: dict[str, tuple[float, str]] = {}
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        if metric not in (reader.fieldnames or []):
            raise FvizError(f"--metric {metric!r}: not a column of {path}")
        estimators = set()
        for line, row in enumerate(reader, 2):
            estimators.add(row["estimator"])
            if row["estimator"] == side.estimator:
                v = csv_number(row, metric, f"{path}:{line}")
                out[row["name"]] = (v, row.get("pair_error") or row.get("error") or "")
    if not out:
        raise FvizError(f"estimator {side.estimator!r}: not in {path} (it has {', '.join(sorted(estimators))})")
    return out


def _fails(v: float, error: str, threshold: float, higher_better: bool) -> bool:
    return bool(error) or not math.isfinite(v) or (v < threshold if higher_better else v > threshold)


def compare(a: Side, b: Side, metric: str = "sed_median", fail_threshold: float = FAIL_THRESHOLD,
            tie: float = 0.0) -> Comparison:
    """Pair-by-pair comparison of side a against side b."""
    if a.estimator == b.estimator and Path(a.run).resolve() == Path(b.run).resolve():
        raise FvizError(f"compare: a and b are both {a.estimator} of {a.run}; compare two estimators or two runs")
    va, vb = read_side(a, metric), read_side(b, metric)
    hb = metric in HIGHER_IS_BETTER
    c = Comparison(a, b, metric, fail_threshold)
    c.missing = sorted(set(va) ^ set(vb))
    for name in [n for n in va if n in vb]:
        (x, ea), (y, eb) = va[name], vb[name]
        c.values[name] = (x, y)
        fa, fb = _fails(x, ea, fail_threshold, hb), _fails(y, eb, fail_threshold, hb)
        if fa and fb:
            c.both_fail.append(name)
        elif fa:
            c.only_a_fails.append(name)
        elif fb:
            c.only_b_fails.append(name)
        if math.isfinite(x) and math.isfinite(y) and not ea and not eb:
            d = (y - x) if not hb else (x - y)  # > 0: a better
            (c.wins if d > tie else c.losses if d < -tie else c.ties).append(name)
    return c


def _median_diff(c: Comparison) -> float:
    import numpy as np

    d = [x - y for x, y in c.values.values() if math.isfinite(x) and math.isfinite(y)]
    return float(np.median(d)) if d else math.nan


def summary_rows(c: Comparison) -> list[tuple[str, str]]:
    """(what, count) lines of the comparison, as printed and written."""
    na, nb = c.names
    return [
        ("pairs compared", str(len(c.values))),
        (f"{na} better (wins)", str(len(c.wins))),
        (f"{nb} better (losses)", str(len(c.losses))),
        ("ties", str(len(c.ties))),
        (f"only {na} fails", str(len(c.only_a_fails))),
        (f"only {nb} fails", str(len(c.only_b_fails))),
        ("both fail", str(len(c.both_fail))),
        (f"median {c.metric} a - b", f"{_median_diff(c):.4g}"),
        ("pairs in one run only", str(len(c.missing))),
    ]


def _what(c: Comparison) -> str:
    """The line naming what a compare.md compares (a later compare with another one must not replace it silently)."""
    return f"a = `{c.a.label}`, b = `{c.b.label}`, metric `{c.metric}`."


def compare_markdown(c: Comparison) -> str:
    worse = "below" if c.metric in HIGHER_IS_BETTER else "above"
    na, nb = c.names
    lines = [
        "# fviz compare",
        "",
        _what(c),
        "",
        f"A side fails on a pair when it errors, has no value, or its {c.metric} is {worse} {c.fail_threshold:g}. "
        "Wins and losses count pairs where both have a value.",
        "",
        "| | count |",
        "|---|---|",
        *[f"| {what} | {n} |" for what, n in summary_rows(c)],
    ]
    for title, names in ((f"Only {na} fails", c.only_a_fails), (f"Only {nb} fails", c.only_b_fails)):
        lines += ["", f"## {title}", "", "| pair | a | b |", "|---|---|---|"]
        lines += [f"| `{n}` | {_v(c, n, 0)} | {_v(c, n, 1)} |" for n in names] or ["| (none) | | |"]
    return "\n".join(lines) + "\n"


def _v(c: Comparison, name: str, i: int) -> str:
    v = c.values[name][i]
    return f"{v:.4g}" if math.isfinite(v) else "failed"


def write_compare(c: Comparison, path: Path, force: bool = False) -> tuple[Path, bool]:
    """Write the comparison to ``path`` (atomically): (path, whether a previous file was replaced).

    A file there holding another comparison is replaced only with ``force``; the same comparison
    (e.g. after the run was resumed) is simply brought up to date.
    """
    path = Path(path)
    replaced = path.exists()
    if replaced and not path.is_file():
        raise FvizError(f"--out {path}: not a regular file")
    if replaced and not force:
        try:
            previous = path.read_text() if path.is_file() else ""
        except (OSError, UnicodeDecodeError):
            previous = ""
        if _what(c) not in previous.splitlines():
            raise FvizError(f"{path} holds another comparison: add --force to replace it, or write to --out OTHER.md")
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_text(path, compare_markdown(c)), replaced
