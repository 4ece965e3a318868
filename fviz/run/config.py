"""A run's configuration: which pairs (a :class:`fviz.data.selection.Selection`, shards), which
estimators (options, the constant-F baselines ``oracle-mean`` and ``mean:SEL``), and the names of the files
a run writes."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any, Callable

import numpy as np

from fviz.data.pair import PairId
from fviz.data.selection import (  # noqa: F401 (re-exported: a run's selection)
    KittiSource,
    Selection,
    SyntheticSource,
    user_source_conflict,
)
from fviz.errors import FvizError
from fviz.estimators.baselines import constant_estimator, mean_fundamental
from fviz.estimators.options import MAX_KEYPOINTS, EstimatorOptions
from fviz.estimators.registry import MEAN_PREFIX, ORACLE_MEAN, is_run_baseline
from fviz.evaluate import EVAL_THRESHOLD_PX, GT_NAME

RUN_FILE = "run.json"
RESULTS_FILE = "results.jsonl"
CSV_FILE = "metrics.csv"
PARQUET_FILE = "metrics.parquet"
SUMMARY_FILE = "summary.md"
RRD_FILE = "eval.rrd"
PAYLOAD_DIR = "pairs"

SUMMARY_JSON = "summary.json"
ESTIMATOR_TIMEOUT_S = 600.0  # default --estimator-timeout: one estimator on one pair
MIN_PAIRS_PER_WORKER = 4  # fewer pairs than this per process: starting one costs more than it saves
CACHE_ITEMS = 16  # features kept per worker, plus 2 per frame of the largest step (frame-major order)

# Columns of the CSV that are text or integers; every other column is a float.
TEXT_COLUMNS = ("name", "source", "root", "sequence", "kind", "estimator", "norm", "error", "pair_error",
                "image_a", "image_b", "path_a", "path_b", "ground_truth")
INT_COLUMNS = ("index", "frame_a", "frame_b", "cam_a", "cam_b", "n_matches", "n_eval")
ID_COLUMNS = ("index", "frame_a", "frame_b", "cam_a", "cam_b")  # integers that name a pair, not metrics


def csv_number(row: dict[str, Any], column: str, where: str) -> float:
    """The number in ``column`` of a metrics.csv row (NaN when empty or "nan"); FvizError naming ``where``
    (file:line) and the column for any other text."""
    text = row.get(column)
    if text in (None, "", "nan", "NaN"):
        return float("nan")
    try:
        return float(text)
    except (TypeError, ValueError):
        raise FvizError(f"{where}: column {column!r} holds {str(text)[:30]!r}, not a number") from None


def check_metric_column(metric: str, flag: str = "--metric") -> None:
    """A one-line error when ``metric`` names a text or identity column of metrics.csv."""
    if metric in TEXT_COLUMNS or metric in ID_COLUMNS:
        raise FvizError(f"{flag} {metric}: a {'text' if metric in TEXT_COLUMNS else 'pair'} column, not a metric "
                        "(e.g. sed_median, pose_err_deg, nsgd, inlier_ratio)")


# Metrics summarised per estimator in summary.md (mean, median, p90, p99). f_dist is not one: see fviz.evaluate.
SUMMARY_METRICS = ("sed_median", "sampson_median", "pose_err_deg", "rot_err_deg", "trans_err_deg", "nsgd",
                   "gt_inlier_ratio", "epi_abs", "epi_sqr", "inlier_ratio", "epipole_err_deg", "seconds")
PERCENTILES = (90, 99)
PAPER_NORMS = ("fbn", "abs", "etr")
PAPER_COLUMNS = tuple(f"epi_{m}_{n}" for n in PAPER_NORMS for m in ("abs", "sqr"))


# ------------------------------------------------------------------------------------ selection




def parse_shard(text: str) -> tuple[int, int]:
    """``i/n`` (0 <= i < n) -> (i, n)."""
    try:
        i, n = (int(p) for p in text.split("/"))
    except ValueError:
        raise FvizError(f"--shard {text!r}: expected i/n, e.g. 0/4") from None
    if not 0 <= i < n:
        raise FvizError(f"--shard {text}: need 0 <= i < n")
    return i, n


def shard_slice(ids: list[PairId], shard: tuple[int, int] | None) -> range:
    """Shard i of n: the i-th of n contiguous blocks of the frame-major pairs, balanced in frames.

    Detecting features is what a pair costs, so the blocks hold about the same number of images
    (frames x cameras, counting those a block shares with its neighbour) rather than of pairs, and
    they split only between pairs of different first frames (a frame's pairs stay in one job).
    """
    if shard is None:
        return range(len(ids))
    i, n = shard
    bounds = _balanced_blocks(ids, n)
    return range(bounds[i], bounds[i + 1]) if i + 1 < len(bounds) else range(len(ids), len(ids))


def _balanced_blocks(ids: list[PairId], n: int) -> list[int]:
    """Start indices of at most ``n`` contiguous blocks (then ``len(ids)``) whose largest image count is
    the smallest possible: a binary search on that count, each step packing pairs greedily."""
    groups = [k for k in range(len(ids)) if k == 0 or (ids[k].sequence, ids[k].frame_a) != (ids[k - 1].sequence, ids[k - 1].frame_a)]
    keys = [{key for pid in ids[a:b] for key in (pid.key_a, pid.key_b)} for a, b in zip(groups, [*groups[1:], len(ids)])]

    def pack(limit: int) -> list[int]:
        bounds, block = [0], set()
        for g, group_keys in zip(groups, keys):
            if block and len(block | group_keys) > limit:
                bounds.append(g)
                block = set()
            block |= group_keys
        return bounds + [len(ids)]

    lo, hi = 1, len(set().union(*keys)) if keys else 1
    while lo < hi:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if len(pack(mid)) - 1 <= n else (mid + 1, hi)
    return pack(lo)


@dataclass(frozen=True)
class RunConfig:
    """Everything that determines a run's results (what run.json holds)."""

    selection: Selection
    options: EstimatorOptions
    norm: str = "fbn"
    eval_threshold: float = EVAL_THRESHOLD_PX
    full: bool = False
    shard: tuple[int, int] | None = None
    baseline_F: dict[str, tuple[float, ...]] = field(default_factory=dict)  # spec -> 9 numbers, set by :func:`prepare`
    estimator_timeout: float = ESTIMATOR_TIMEOUT_S  # seconds one estimator may take on one pair

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["selection"] = self.selection.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RunConfig":
        """run.json back to a configuration: every field checked against its type (a one-line FvizError
        naming the field), then the selection, norm and thresholds as a run's flags are (:func:`check`)."""
        from fviz.schema import convert

        config = convert(d, cls, "")
        if config.shard is not None and not 0 <= config.shard[0] < config.shard[1]:
            raise FvizError(f"'shard' {list(config.shard)}: need 0 <= i < n")
        if any(len(v) != 9 for v in config.baseline_F.values()):
            raise FvizError("'baseline_F': 9 numbers per baseline expected")
        check(config)
        return config

    def fingerprint(self, ref: dict[str, Any]) -> str:
        """What made a record of the pair ``ref``: the settings every estimator's result depends on (feature
        and robust options, norm, evaluation threshold) and the pair itself. A record whose fingerprint
        differs was made by another configuration and is never reused."""
        import hashlib
        import json

        if "_fingerprinted" not in self.__dict__:  # the settings part, once per configuration (it is frozen)
            d = self.comparable()
            object.__setattr__(self, "_fingerprinted", {"options": d["options"], "norm": d["norm"],
                                                        "eval_threshold": float(d["eval_threshold"])})
        settings = {**self.__dict__["_fingerprinted"], "pair": {k: v for k, v in ref.items() if k != "name"}}
        inputs = self.input_digest(ref.get("name"))
        if inputs is not None:  # KITTI and synthetic pairs have none (their records keep their fingerprints)
            settings["inputs"] = inputs
        return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:20]

    def input_digest(self, name: str | None) -> str | None:
        """A digest of the content the pair ``name`` is read from, where the source is a user's: its pairs-file
        line (names, rotations, cameras, pose), its COLMAP cameras and poses, its --matches / --gt-matches file.
        An edited input makes the pair's records another configuration's (evaluated again on --resume)."""
        if "_digests" not in self.__dict__:  # per pair, when first asked (a worker asks only for its own pairs)
            source = self.selection.source()
            fn = getattr(source, "input_digest", None)
            object.__setattr__(self, "_digests", {})
            object.__setattr__(self, "_digest_of", (fn, {pid.name: pid for pid in source.pair_ids()} if fn else {}))
        digests, (fn, pids) = self.__dict__["_digests"], self.__dict__["_digest_of"]
        if name not in digests:
            digests[name] = fn(pids[name]) if fn is not None and name in pids else None
        return digests[name]

    def estimator_names(self) -> list[str]:
        """Display names, in order (``gt`` not included)."""
        from fviz.estimators.registry import display_names

        return display_names(self.options.names)

    def series_names(self) -> list[str]:
        """The order of PairResult.estimators: the ground truth, then the estimators."""
        return [GT_NAME, *self.estimator_names()]

    def pairs(self, source=None) -> list[tuple[int, PairId]]:
        """(index in the whole selection, pair) of this run's shard."""
        ids = (source or self.selection.source()).pair_ids()
        return [(i, ids[i]) for i in shard_slice(ids, self.shard)]

    def comparable(self) -> dict[str, Any]:
        """What must agree for two runs' records to be mixed (resume, merge): all but the estimator names
        (pairs lacking one are evaluated again), the baselines' F (fixed by names and selection), the shard,
        ``full`` (which only adds payload files) and the estimators' time limit."""
        d = self.to_dict()
        d["options"] = {k: v for k, v in d["options"].items() if k != "names"}
        for key in ("shard", "full", "baseline_F", "estimator_timeout"):
            d.pop(key)
        return d

    def differences(self, new: "RunConfig") -> list[str]:
        """The comparable settings that differ, as ``--flag OURS in the run, THEIRS now`` (a refused resume says which)."""
        ours, theirs = _flatten(self.comparable()), _flatten(new.comparable())
        keys = sorted(k for k in ours.keys() | theirs.keys() if ours.get(k) != theirs.get(k))
        return [f"{_FLAGS.get(k, k)} {_show(k, ours.get(k))} in the run, {_show(k, theirs.get(k))} now" for k in keys]

    def cache_items(self) -> int:
        """Features kept per worker: enough for the frames a frame-major window of pairs shares."""
        return CACHE_ITEMS + 2 * max(self.selection.steps)


# run.json keys -> the flags that set them (differences are reported in the user's words)
_FLAGS = {"selection.kitti_root": "--kitti-root", "selection.sequence": "--sequence", "selection.drive": "--drive",
          "selection.kinds": "--pair", "selection.steps": "--step", "selection.cams": "--cams", "selection.frames": "--frames",
          "selection.synthetic": "--synthetic", "selection.seeds": "--seeds", "selection.pairs": "--pairs",
          "selection.images": "--images", "selection.colmap": "--colmap", "selection.min_shared": "--min-shared",
          "selection.matches": "--matches", "selection.gt_matches": "--gt-matches", "selection.image_a": "--image-a",
          "selection.image_b": "--image-b", "selection.K": "--K", "selection.K_a": "--K-a", "selection.K_b": "--K-b",
          "selection.T_ab": "--T-ab", "selection.F_gt": "--F-gt", "options.features": "--features",
          "options.max_keypoints": "--max-keypoints", "options.ratio": "--ratio", "options.mutual": "--mutual",
          "options.threshold": "--threshold", "options.confidence": "--confidence", "options.max_iters": "--max-iters",
          "options.seed": "--seed", "norm": "--norm", "eval_threshold": "--eval-threshold",
          "baseline_F": "a baseline's F"}


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out = {}
    for k, v in d.items():
        out.update(_flatten(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
    return out


def _show(key: str, v: Any) -> str:
    if v is None:
        return "(none)" if key == "baseline_F" else "(default)"
    if key == "baseline_F":
        return "[" + " ".join(f"{x:.3g}" for x in v) + "]"
    if isinstance(v, (list, tuple)):
        sep = ":" if key in ("selection.frames", "selection.seeds") else ","
        return sep.join("" if x is None else str(x) for x in v)
    return str(v)


def baseline_selections(sel: Selection, spec: str) -> list[Selection]:
    """The pairs whose mean ground-truth F is the baseline ``spec``: the evaluated ones for ``oracle-mean``;
    for ``mean:SEL`` the same kinds, steps and cameras over all frames of other sequences or drives
    (``mean:01,02``) or over other synthetic seeds (``mean:A:B``). Overlap with the evaluated pairs is refused."""
    if spec == ORACLE_MEAN:
        return [sel]
    what = spec[len(MEAN_PREFIX):]
    if sel.user:
        source = "--pairs" if sel.pairs and not sel.colmap else "--colmap" if sel.colmap else "--image-a/--image-b"
        raise FvizError(f"--estimator {spec}: mean:SEQ averages the ground truth of other KITTI sequences (mean:A:B: "
                        f"other synthetic seeds); a {source} run has no sequence to average: use oracle-mean (the "
                        "evaluated pairs' own mean F, an oracle) or ahead")
    if sel.synthetic:
        try:
            a, b = (int(v) for v in what.split(":"))
        except ValueError:
            raise FvizError(f"--estimator {spec}: expected mean:A:B (synthetic seeds A .. B-1)") from None
        if not 0 <= a < b:
            raise FvizError(f"--estimator {spec}: need 0 <= A < B")
        if a < sel.seeds[1] and sel.seeds[0] < b:
            raise FvizError(f"--estimator {spec}: seeds overlap the evaluated ones ({sel.seeds[0]}:{sel.seeds[1]}); "
                            "that would be the oracle-mean")
        return [replace(sel, seeds=(a, b))]
    names = [n.strip() for n in what.split(",")]
    if not all(names):
        raise FvizError(f"--estimator {spec}: expected mean:SEQ[,SEQ...] (odometry sequences or raw drives)")
    if sel.sequence in names or sel.drive in names:
        raise FvizError(f"--estimator {spec}: {sel.sequence or sel.drive} is the evaluated sequence; its mean F is "
                        "the oracle-mean: name other sequences")
    return [replace(sel, sequence=None if "_drive_" in n else n, drive=n if "_drive_" in n else None, frames=(None, None))
            for n in names]


def baseline_fundamental(sel: Selection, spec: str) -> np.ndarray:
    """The constant F of a run-level baseline (:func:`baseline_selections`)."""
    sels = baseline_selections(sel, spec)
    skipped: list[str] = []

    def all_gt():
        for s in sels:
            source = s.source()
            for pid in source.pair_ids():
                try:
                    F = source.ground_truth(pid)
                except FvizError as exc:  # a pair without F (no motion): the baseline is the mean of the others
                    skipped.append(str(exc))
                    continue
                if F is None:  # a pair without ground truth (a names-only pairs line)
                    skipped.append(f"the pair {pid.name} has no ground truth")
                else:
                    yield F

    try:
        F = mean_fundamental(all_gt())
    except FvizError:
        if not skipped:
            raise
        raise FvizError(f"--estimator {spec}: no pair of its selection has a ground-truth F ({skipped[0]})") from None
    if skipped:
        import sys

        print(f"note: --estimator {spec}: {len(skipped)} pairs without a ground-truth F left out of the mean "
              f"(first: {skipped[0]})", file=sys.stderr)
    return F


def check(config: RunConfig) -> None:
    """One-line errors for settings out of range (the flags' own checks, again for a run.json)."""
    import math

    from fviz.geometry import NORMS

    o = config.options
    if config.norm not in NORMS:
        raise FvizError(f"--norm {config.norm!r}: choose one of {', '.join(NORMS)}")
    if config.eval_threshold <= 0:
        raise FvizError(f"--eval-threshold {config.eval_threshold}: must be > 0")
    if not (config.estimator_timeout > 0 and math.isfinite(config.estimator_timeout)):
        raise FvizError(f"--estimator-timeout {config.estimator_timeout}: must be a number of seconds > 0")
    check_options(o)


def check_options(o: EstimatorOptions) -> None:
    """The ranges of the estimator options (a keypoint count OpenCV accepts, a confidence in (0, 1], ...)."""
    rules = (("--max-keypoints", o.max_keypoints, 1 <= o.max_keypoints <= MAX_KEYPOINTS, f"must be 1 .. {MAX_KEYPOINTS}"),
             ("--ratio", o.ratio, 0 < o.ratio <= 1, "must be a number in (0, 1]"),
             ("--threshold", o.threshold, o.threshold > 0, "must be a number > 0"),
             ("--confidence", o.confidence, 0 < o.confidence <= 1, "must be a number in (0, 1]"),
             ("--max-iters", o.max_iters, 1 <= o.max_iters <= 2**31 - 1, "must be 1 .. 2147483647"),
             ("--seed", o.seed, 0 <= o.seed <= 2**31 - 1, "must be 0 .. 2147483647"))
    for flag, value, ok, rule in rules:
        if not ok:
            raise FvizError(f"{flag} {value}: {rule}")


def prepare(config: RunConfig) -> RunConfig:
    """Validate the estimators and the selection (one-line errors) and fix the constant-F baselines
    on the whole selection (not the shard: shards then merge to one run's results)."""
    check(config)
    names = config.options.names
    if len(set(names)) != len(names):
        raise FvizError(f"--estimator: repeated name in {', '.join(names)}")
    if not names:
        raise FvizError("--estimator: give at least one")
    replace(config.options, names=tuple(n for n in names if not is_run_baseline(n))).estimators()
    config.options.feature_config()
    config.selection.source().pair_ids()
    config = _without_oracles_if_no_gt(config)
    missing = [n for n in names if is_run_baseline(n) and n not in config.baseline_F]
    if missing:
        fixed = {n: tuple(float(v) for v in baseline_fundamental(config.selection, n).ravel()) for n in missing}
        config = replace(config, baseline_F={**config.baseline_F, **fixed})
    return config


def known_without_gt(source) -> bool:
    """Whether no pair of ``source`` has ground truth, known without reading an image: a pairs file of names only,
    two images without --T-ab / --F-gt (and no --gt-matches)."""
    from fviz.data.pairsfile import PairsSource
    from fviz.data.sources import TwoImagesSource, WithCorrespondences

    if isinstance(source, WithCorrespondences):
        if source.gt_matches is not None:
            return False
        source = source.source
    if isinstance(source, PairsSource):
        return all(source.lines[pid.frame_a].T is None for pid in source.pair_ids())
    if isinstance(source, TwoImagesSource):
        return source.pair0.F_gt is None
    return False


def _without_oracles_if_no_gt(config: RunConfig) -> RunConfig:
    """A threshold sweep's per-pair oracles (``NAME@oracle``) pick a threshold by the ground truth: on a selection
    without any, they are left out with a note (an error when nothing else is left)."""
    from fviz.estimators.sweep import ORACLE, split_threshold

    names = config.options.names
    oracles = [n for n in names if (split_threshold(n)[1] or "").startswith(ORACLE)]
    if not oracles or not known_without_gt(config.selection.source()):
        return config
    why = "picks each pair's threshold by its ground truth, and no pair of the selection has one"
    rest = tuple(n for n in names if n not in oracles)
    if not rest:
        raise FvizError(f"--estimator {oracles[0]}: {why}")
    import sys

    print(f"note: {', '.join(oracles)} left out: the per-pair oracle {why}", file=sys.stderr)
    return replace(config, options=replace(config.options, names=rest))


def resolve_estimators(config: RunConfig) -> list[tuple[str, Callable]]:
    """[(display name, fn)] in the order of ``--estimator``, the run-level baselines included."""
    others = replace(config.options, names=tuple(n for n in config.options.names if not is_run_baseline(n)))
    resolved = iter(fn for _, fn in others.estimators())
    fns = [constant_estimator(config.baseline_F[n]) if is_run_baseline(n) else next(resolved) for n in config.options.names]
    return list(zip(config.estimator_names(), fns))  # unique names, as in every report


# ------------------------------------------------------------------------------ one pair
