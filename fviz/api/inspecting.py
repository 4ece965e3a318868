"""``fviz inspect pair`` around :func:`fviz.inspect_pair`: its checks before any work (flags, ``--probe-by``), the
estimators resolved once, the table it prints and the error when a pair has too few matches."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

from fviz.errors import FvizError

if TYPE_CHECKING:  # pragma: no cover
    from fviz.data.pair import Pair


def check_flags(norm: str, lines: int, probe: int, out: Path | None) -> None:
    """--norm, --lines, --probe and --out (a folder or special file is refused) before any work."""
    from fviz.geometry import NORMS

    if norm not in NORMS:
        raise FvizError(f"--norm {norm!r}: choose one of {', '.join(NORMS)}")
    if lines < 0:
        raise FvizError(f"--lines {lines}: must be >= 0")
    if probe < 0:
        raise FvizError(f"--probe {probe}: must be >= 0")
    if out is not None:
        from fviz.atomic import target

        target(out)


def estimators(names: Sequence[str], features: str, max_keypoints: int, ratio: float, mutual: bool, threshold: float,
               confidence: float, max_iters: int, seed: int) -> list[tuple[str, Any]]:
    """[(name, fn)] of the estimator specs, resolved once before the pair is loaded (a deep model loads once; a bad
    name fails first)."""
    from fviz.estimators.options import EstimatorOptions

    return EstimatorOptions(tuple(names), features, max_keypoints, ratio, mutual, threshold, confidence, max_iters,
                            seed).estimators()


def check_probe_by(probe_by: str | None, pair: Pair, ests: Sequence[tuple[str, Any]], features: str) -> None:
    """--probe-by names an estimator of the run, the ground truth (when the pair has one) or 'score' (your
    matches' scores): checked once the pair is loaded, before the features and estimators run."""
    from fviz.estimators.sweep import ORACLE_SUFFIX
    from fviz.record.layout import GT
    from fviz.record.probe import PROBE_BY_SCORE

    if probe_by is None:
        return
    if probe_by == PROBE_BY_SCORE:  # scores: a user's matches' own, or a learned matcher's
        if (pair.matches is not None and pair.matches.scores is None) or (pair.matches is None and features in ("sift", "orb", "akaze")):
            raise FvizError(f"--probe-by {probe_by}: these matches have no scores (give --matches with the matcher's scores)")
        return
    names = [n for n, _ in ests if pair.has_gt or not n.endswith(ORACLE_SUFFIX)] + ([GT] if pair.has_gt else [])
    if probe_by not in names:
        raise FvizError(f"--probe-by {probe_by}: not an estimator of this pair ({', '.join(names)}; or score)")


def prestart_rerun() -> None:
    """Import rerun in the background (~0.5 s) while the features are computed."""
    from fviz.run.prestart import import_in_background

    import_in_background("rerun")


def check_enough_matches(pair: Pair, result, path: Path) -> None:
    """The error of a pair with too few matches for any estimator, once its recording is written."""
    from fviz.evaluate import MIN_MATCHES, too_few_matches

    if too_few_matches(result):
        raise FvizError(
            f"only {result.n_matches} matches between {pair.extra.get('path_a', 'image a')} and "
            f"{pair.extra.get('path_b', 'image b')} ({MIN_MATCHES} needed); recorded in {path}"
        )


# The table's columns: (metric, header). Headers short enough never to be cut (a pipe gives rich 80 columns);
# the caption says what each is.
TABLE_COLUMNS = (("sed_median", "SED px"), ("sampson_median", "Sampson px"), ("rot_err_deg", "rot °"),
                 ("trans_err_deg", "trans °"), ("nsgd", "NSGD"), ("inlier_ratio", "inliers"),
                 ("epipole_err_deg", "epipole °"), ("epi_abs", "EPI-ABS"), ("epi_sqr", "EPI-SQR"),
                 ("agreement_nsgd", "NSGD to closest"))
TABLE_CAPTION = ("SED / Sampson px: medians over the evaluation matches; rot / trans / epipole °: errors of the recovered "
                 "rotation, translation direction and epipole; NSGD: FM-Bench's normalized distance to F_gt; inliers: "
                 "share of all matches; time s: the estimator's run time. Every metric: --json.")


@dataclass(frozen=True)
class Table:
    """inspect's table: ``title``, ``caption``, the metric ``headers`` (then "time s"), ``rows`` (one per F: its name,
    a cell per header, its time; a failed F: its name, the error in rich markup, blanks) and the ``notes`` below it."""

    title: str
    caption: str
    headers: list[str]
    rows: list[list[str]]
    notes: list[str]


def table(result) -> Table:
    """The table of a :func:`fviz.inspect_pair` result, with the columns some F has."""
    from fviz.evaluate import agreement_text
    from fviz.record.pair_text import precision_lines

    cols = [(c, h) for c, h in TABLE_COLUMNS if any(c in r.metrics for r in result.estimators)]
    title = (f"{result.pair['name']}  ({result.n_matches} matches, {result.n_eval} for evaluation; "
             f"EPI means under {result.norm.upper()})")
    rows = [[r.name, f"[red]failed: {r.error.splitlines()[0]}[/red]", *[""] * (len(cols) - 1), ""] if r.error else
            [r.name, *(f"{r.metrics.get(c, float('nan')):.4g}" for c, _ in cols), f"{r.seconds:.3f}"]
            for r in result.estimators]
    notes = [] if result.has_gt else [
        "no ground truth: the estimators are compared with each other (SED and inliers over all matches; "
        f"agreement_nsgd = NSGD to the closest other estimator): {agreement_text(result.agreement)}"]
    return Table(title, TABLE_CAPTION, [h for _, h in cols], rows, notes + precision_lines(result.match_precision)[1:])
