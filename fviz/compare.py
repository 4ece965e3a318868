"""Compare two estimators pair by pair: wins, losses, ties, and the pairs where exactly one fails.

Sides come from the metrics.csv of ``fviz eval`` runs: two estimators of one run, or one estimator
of two runs (pairs matched by name). A side has an *error* on a pair when the pair or the estimator errored
(no F, no value; eval's ``errors (no F)``); it *fails* the metric when it has no value or its value is past the
metric's own threshold
(:data:`fviz.verdicts.FAIL_RULES`: ``sed_median > 2 px``, ``nsgd > 0.05``, ``inlier_ratio < 0.5``...; above it, or
below it where higher is better), or past ``fail_threshold`` when given. A metric without a threshold fails only where
there is no value. Every count of "fails" is labelled with its rule (:func:`fviz.verdicts.fails_label`). Wins and
losses count the pairs where both sides have a value; a difference within the tolerance (``tie`` absolute,
``tie_rel`` relative to the larger of the two values) is a tie.

The pairs where only one side fails are listed with where they sit in the run (one stretch of consecutive pairs is
one event of the sequence: a turn, a stop) and the ``fviz inspect pair`` command that reopens each; compare.rrd
beside compare.md plots both sides per pair (:mod:`fviz.record.compare_plot`).

Beside the counts: the per-pair differences (a - b) and Wilcoxon's signed-rank test of them (two-sided;
exact over the 2^n sign flips of the ranks for n <= EXACT_MAX_N, ties averaged, else the normal approximation
with tie and continuity corrections), on the pairs where both sides have a value.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

from fviz.atomic import write_text
from fviz.errors import FvizError
from fviz.stats import EXACT_MAX_N, Wilcoxon, signed_ranks, wilcoxon_signed_rank  # noqa: F401 (re-exported)
from fviz.verdicts import ERROR, ERRORS, HIGHER_IS_BETTER, fails, fails_column, fails_label

COMPARE_FILE = "compare.md"
FAIL_THRESHOLD = None  # the metric's own threshold (fviz.verdicts); --fail-threshold replaces it
TIE_REL = 0.05  # default: values within 5 % of the larger one are a tie (a 0.21 vs 0.2101 px "win" says nothing)
NO_VALUE = "errors (no F or no value)"  # a side's pairs without a value: summary rows and compare.md


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
    fail_threshold: float | None
    wins: list[str] = field(default_factory=list)  # a better
    losses: list[str] = field(default_factory=list)  # b better
    ties: list[str] = field(default_factory=list)
    only_a_fails: list[str] = field(default_factory=list)
    only_b_fails: list[str] = field(default_factory=list)
    both_fail: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)  # pairs of one side only
    a_errors: list[str] = field(default_factory=list)  # no value: the pair or the estimator errored
    b_errors: list[str] = field(default_factory=list)
    values: dict[str, tuple[float, float]] = field(default_factory=dict)
    tie: float = 0.0
    tie_rel: float = TIE_REL

    @property
    def fails_label(self) -> str:
        """What "fails" means here: "sed_median > 2 px", "inlier_ratio < 0.5", "no value"."""
        return fails_label(self.metric, self.fail_threshold)

    def differences(self) -> list[tuple[str, float, float, float]]:
        """(pair, a, b, a - b) where both sides have a value, largest |a - b| first."""
        rows = [(n, x, y, x - y) for n, (x, y) in self.values.items() if math.isfinite(x) and math.isfinite(y)]
        return sorted(rows, key=lambda r: (-abs(r[3]), r[0]))

    def wilcoxon(self) -> "Wilcoxon":
        return wilcoxon_signed_rank([d for *_, d in self.differences()])

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
                # the ground truth's F (fviz.evaluate.GT_NAME) does not depend on the matches: a pair with too few is no
                # error of it
                pair_error = "" if side.estimator == "gt" else row.get("pair_error")
                out[row["name"]] = (v, pair_error or row.get("error") or "")
    if not out:
        raise FvizError(f"estimator {side.estimator!r}: not in {path} (it has {', '.join(sorted(estimators))})")
    return out


def is_tie(x: float, y: float, tie: float = 0.0, tie_rel: float = TIE_REL) -> bool:
    """Whether two values differ by no more than ``tie`` or ``tie_rel`` of the larger magnitude."""
    return abs(x - y) <= max(tie, tie_rel * max(abs(x), abs(y)))


def compare(a: Side, b: Side, metric: str = "sed_median", fail_threshold: float | None = FAIL_THRESHOLD,
            tie: float = 0.0, tie_rel: float = TIE_REL) -> Comparison:
    """Pair-by-pair comparison of side a against side b."""
    if a.estimator == b.estimator and Path(a.run).resolve() == Path(b.run).resolve():
        raise FvizError(f"compare: a and b are both {a.estimator} of {a.run}; compare two estimators or two runs")
    return compare_values(a, b, metric, read_side(a, metric), read_side(b, metric), fail_threshold, tie, tie_rel)


def compare_values(a: Side, b: Side, metric: str, va: dict[str, tuple[float, str]], vb: dict[str, tuple[float, str]],
                   fail_threshold: float | None = FAIL_THRESHOLD, tie: float = 0.0, tie_rel: float = TIE_REL) -> Comparison:
    """:func:`compare` of values already read: pair name -> (value or NaN, error message or "") of each side
    (what :func:`read_side` gives; :mod:`fviz.train.heldout` passes its own per-pair figures)."""
    hb = metric in HIGHER_IS_BETTER
    c = Comparison(a, b, metric, fail_threshold, tie=tie, tie_rel=tie_rel)
    c.missing = sorted(set(va) ^ set(vb))
    for name in [n for n in va if n in vb]:
        (x, ea), (y, eb) = va[name], vb[name]
        c.values[name] = (x, y)
        fa, fb = fails(metric, x, ea, fail_threshold), fails(metric, y, eb, fail_threshold)
        for errors, v, e in ((c.a_errors, x, ea), (c.b_errors, y, eb)):
            if e or not math.isfinite(v):
                errors.append(name)
        if fa and fb:
            c.both_fail.append(name)
        elif fa:
            c.only_a_fails.append(name)
        elif fb:
            c.only_b_fails.append(name)
        if math.isfinite(x) and math.isfinite(y) and not ea and not eb:
            d = (y - x) if not hb else (x - y)  # > 0: a better
            (c.ties if is_tie(x, y, tie, tie_rel) else c.wins if d > 0 else c.losses).append(name)
    return c


def _median_diff(c: Comparison) -> float:
    import numpy as np

    d = [x - y for x, y in c.values.values() if math.isfinite(x) and math.isfinite(y)]
    return float(np.median(d)) if d else math.nan


def summary_rows(c: Comparison) -> list[tuple[str, str]]:
    """(what, count) lines of the comparison, as printed and written."""
    na, nb = c.names
    label = c.fails_label
    return [
        ("pairs compared", str(len(c.values))),
        (f"{na} better (wins)", str(len(c.wins))),
        (f"{nb} better (losses)", str(len(c.losses))),
        ("ties", str(len(c.ties))),
        (f"{na}: {NO_VALUE}", str(len(c.a_errors))),
        (f"{nb}: {NO_VALUE}", str(len(c.b_errors))),
        (f"only {na} fails ({label})", str(len(c.only_a_fails))),
        (f"only {nb} fails ({label})", str(len(c.only_b_fails))),
        (f"both fail ({label})", str(len(c.both_fail))),
        (f"median {c.metric} a - b", f"{_median_diff(c):.4g}"),
        ("Wilcoxon signed-rank p (two-sided)", _p_text(c.wilcoxon())),
        ("pairs in one run only", str(len(c.missing))),
    ]


def _p_text(w: Wilcoxon) -> str:
    if w.method == "none":
        return "n/a (no pair differs)"
    return f"{w.p:.3g} ({w.method}, n = {w.n}, W+ = {w.w_plus:g}, W- = {w.w_minus:g})"


def _tie_text(c: Comparison) -> str:
    parts = ([f"{c.tie:g}"] if c.tie > 0 else []) + ([f"{c.tie_rel:.0%} of the larger value"] if c.tie_rel > 0 else [])
    return "differences within " + " or ".join(parts) + " are ties" if parts else "no tolerance: any difference counts"


def _what(c: Comparison) -> str:
    """The line naming what a compare.md compares (a later compare with another one must not replace it silently)."""
    return f"a = `{c.a.label}`, b = `{c.b.label}`, metric `{c.metric}`."


@dataclass(frozen=True)
class Place:
    """Where a compared pair sits in run a: its index, its frames (KITTI; else None), the command reopening it."""

    index: int
    frames: tuple[int, int] | None
    command: str


def places_of(run: Path) -> dict[str, Place]:
    """Pair name -> :class:`Place` of every pair of a run (empty for a folder without run.json)."""
    from fviz.run import ResultStore, read_config
    from fviz.triage import inspect_command

    config = read_config(Path(run))
    if config is None:
        return {}
    source = config.selection.source()
    out = {}
    for rec in ResultStore(Path(run)).records():
        ref = rec["ref"]
        frames = (ref["frame_a"], ref["frame_b"]) if ref.get("frame_a") is not None else None
        out[rec["key"]] = Place(rec["index"], frames, inspect_command(config, source, ref))
    return out


def stretches(indices) -> list[tuple[int, int]]:
    """Runs of consecutive integers, first and last of each: [3, 4, 5, 9] -> [(3, 5), (9, 9)]."""
    out: list[list[int]] = []
    for i in sorted(set(indices)):
        if out and i == out[-1][1] + 1:
            out[-1][1] = i
        else:
            out.append([i, i])
    return [(a, b) for a, b in out]


def stretch_text(names: list[str], places: dict[str, Place]) -> str:
    """Where the listed pairs sit in the run: "21 pairs, frames 410-431, consecutive (#410-#430 of the run): one
    stretch of the sequence, one event (a turn? a stop? ...)", or the stretches they form; "" for fewer than 2."""
    at = {places[n].index: places[n] for n in names if n in places}
    if len(at) < 2:
        return ""
    runs = stretches(at)
    frames = all(p.frames for p in at.values())

    def span(a: int, b: int) -> str:
        where = f"#{a}" if a == b else f"#{a}-#{b}"
        return f"frames {at[a].frames[0]}-{at[b].frames[1]} ({where})" if frames else where

    if len(runs) == 1:
        return (f"{len(at)} pairs, {span(*runs[0])}, consecutive: one stretch of the sequence, one event (a turn? a "
                "stop? look at its motion)")
    shown = ", ".join(span(a, b) for a, b in runs[:6]) + (", ..." if len(runs) > 6 else "")
    longest = max(b - a + 1 for a, b in runs)
    return f"{len(at)} pairs in {len(runs)} stretches of consecutive pairs (the longest {longest} pairs): {shown}"


def compare_markdown(c: Comparison, places: dict[str, Place] | None = None) -> str:
    """compare.md; ``places`` (:func:`places_of` run a) add where the listed pairs sit and how to reopen them."""
    places = places or {}
    na, nb = c.names
    rule = (f"its {c.fails_label}" + ("" if c.fail_threshold is None else " (`--fail-threshold`)")
            if c.fails_label != "no value" else f"(`{c.metric}` has no threshold: give `--fail-threshold`)")
    lines = [
        "# fviz compare",
        "",
        _what(c),
        "",
        f"A side has an *error* on a pair when it gave no F there or no value (eval's `{ERRORS}`); it *fails* the "
        f"pair when it has no value or {rule}"
        + (f" (eval's `{fails_column()}` counts the same). " if (c.metric, c.fail_threshold) == ("sed_median", None) else ". ") +
        f"Wins and losses count pairs where both have a value; {_tie_text(c)} (`--tie`, `--tie-rel`). Wilcoxon's "
        "signed-rank test asks whether the per-pair differences a - b are centred on zero (small p: one side is "
        "better across the pairs, not just on a few).",
        "",
        "| | count |",
        "|---|---|",
        *[f"| {what} | {n} |" for what, n in summary_rows(c)],
    ]
    for title, names in ((f"Only {na} fails ({c.fails_label})", c.only_a_fails),
                         (f"Only {nb} fails ({c.fails_label})", c.only_b_fails)):
        lines += ["", f"## {title}", ""]
        lines += [f"{stretch_text(names, places)}.", ""] if stretch_text(names, places) else []
        lines += ["| pair | a | b | reopen it |", "|---|---|---|---|"]
        lines += [f"| `{n}` | {_v(c, n, 0)} | {_v(c, n, 1)} | {_command(c, places, n)} |" for n in names] or ["| (none) | | | |"]
    better = "larger" if c.metric in HIGHER_IS_BETTER else "smaller"
    lines += ["", "## Per pair", "", f"{c.metric} of a and b and their difference, largest |a - b| first ({better} is better).",
              "", "| pair | a | b | a - b | |", "|---|--:|--:|--:|---|"]
    lines += [f"| `{n}` | {x:.4g} | {y:.4g} | {d:+.4g} | {_verdict(c, n, na, nb)} |" for n, x, y, d in c.differences()]
    return "\n".join(lines) + "\n"


def _command(c: Comparison, places: dict[str, Place], name: str) -> str:
    """The commands that reopen a pair: inspect's, and ``fviz open`` from run a's folder (beside run b's pair)."""
    from fviz.triage import open_command

    if name not in places:
        return ""
    versus = c.b.run if Path(c.b.run).absolute() != Path(c.a.run).absolute() else None
    return f"`{places[name].command}`<br>`{open_command(c.a.run, name, versus)}`"


def _verdict(c: Comparison, name: str, na: str, nb: str) -> str:
    return "tie" if name in c.ties else f"{na} better" if name in c.wins else f"{nb} better" if name in c.losses else ""


def _v(c: Comparison, name: str, i: int) -> str:
    v = c.values[name][i]
    return f"{v:.4g}" if math.isfinite(v) else ERROR


def write_compare(c: Comparison, path: Path, force: bool = False, places: dict[str, Place] | None = None) -> tuple[Path, bool]:
    """Write the comparison to ``path`` (atomically) and its plot beside it (``path`` with ``.rrd``): (path,
    whether a previous file was replaced). ``places``: :func:`places_of` run a, default read from it.

    A file there holding another comparison is replaced only with ``force``; the same comparison
    (e.g. after the run was resumed) is simply brought up to date.
    """
    from fviz.record.compare_plot import write_compare_recording

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
    places = places_of(c.a.run) if places is None else places
    markdown = compare_markdown(c, places)
    write_compare_recording(c, recording_path(path), {n: p.index for n, p in places.items()}, markdown)
    return write_text(path, markdown), replaced


def recording_path(markdown: Path) -> Path:
    """compare.rrd beside compare.md (the plot of the same comparison)."""
    rrd = Path(markdown).with_suffix(".rrd")
    return rrd if rrd != Path(markdown) else Path(f"{markdown}.rrd")
