"""What ``fviz summary`` prints: a recording's items (pair name, metrics, errors per index of its main timeline),
read in one pass over the chunks (:mod:`fviz.record.reader`).

Items are the time indices of the ``pair/info`` and ``pair/metrics`` rows on the recording's main timeline
(:func:`fviz.record.reader.main_timeline`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterator

from fviz.errors import FvizError
from fviz.record import layout as L
from fviz.record.reader import (_LOG_TEXT, _ROW_ID, _TEXT, BUILTIN_TIMELINES, _chunks, _contents, _entity, _index_names,
                                _ints, _layout, main_timeline, open_rrd)

_ESTIMATORS = "estimators"  # the names column of ``pair/metrics``


@dataclass(frozen=True)
class Item:
    """One time index of the main timeline (one pair in inspect/eval, one rank in triage).

    index:   the value on the main timeline (int)
    name:    the pair's name from ``pair/info`` (None when not logged)
    metrics: {metric: {estimator: value}} from ``pair/metrics``; NaN where an estimator failed
    errors:  {estimator: message} from ``errors/{estimator}`` (the estimator's error, as in ``inspect --json``)
    times:   {timeline: value} of the other sequence timelines on those rows (e.g. ``{"pair": 7}`` in triage)
    """

    index: int
    name: str | None = None
    metrics: dict[str, dict[str, float]] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)
    times: dict[str, int] = field(default_factory=dict)

    def estimators(self) -> list[str]:
        """Estimator names with a value or an error here, in series order."""
        seen: dict[str, None] = {}
        for per in self.metrics.values():
            seen.update(dict.fromkeys(per))
        seen.update(dict.fromkeys(self.errors))
        return list(seen)


@dataclass(frozen=True)
class RecordingSummary:
    """What a recording holds (see :func:`read_recording`).

    path:          the file read
    app_id:        the recording's application id (``fviz-inspect``, ...)
    recording_id:  its recording id
    timeline:      the main timeline (None when nothing is on a timeline)
    timelines:     every index timeline found, builtin ones included, sorted
    items:         one :class:`Item` per index of the main timeline, ascending
    metrics:       metric names (columns of ``pair/metrics``), sorted
    estimators:    estimator names (``gt`` first), in logged order over the items
    has_blueprint: whether a default blueprint is stored in the file
    entity_paths:  every entity path, sorted (Rerun's internal ``/__properties`` left out)
    """

    path: Path
    app_id: str
    recording_id: str
    timeline: str | None
    timelines: tuple[str, ...]
    items: tuple[Item, ...]
    metrics: tuple[str, ...]
    estimators: tuple[str, ...]
    has_blueprint: bool
    entity_paths: tuple[str, ...]

    def item(self, name_or_index: str | int) -> Item:
        """The item named so (pair name) or at that index; KeyError if absent."""
        by_name = isinstance(name_or_index, str)
        for it in self.items:
            if (it.name if by_name else it.index) == name_or_index:
                return it
        raise KeyError(name_or_index)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: NaN and infinities become None, the path a string."""
        d = asdict(self)
        d["path"] = str(self.path)
        return _nan_to_none(d)


def read_recording(path: str | Path, timeline: str | None = None) -> RecordingSummary:  # noqa: C901 (one pass over the chunks, a branch per entity kind)
    """Summarize a recording: app id, timelines, items (pair name, metrics, errors per index), blueprint,
    entity paths.  timeline: the index timeline of the items (default :func:`main_timeline`)."""
    p = Path(path)
    reader = open_rrd(p)
    rec = reader.recordings()[0]
    contents = _contents(reader)
    paths, all_timelines = contents.paths, sorted(contents.timelines)
    tl = timeline or main_timeline(all_timelines)
    if timeline is not None and timeline not in all_timelines:
        raise FvizError(f"{p}: no timeline {timeline!r} (it has {', '.join(all_timelines) or 'none'})")
    entities = sorted({_layout(e) for e in paths if not e.startswith("/__")})
    error_prefix = L.error("")

    values: dict[int, dict[str, list[float]]] = {}  # index -> metric -> values in estimator order
    names: dict[int, list[str]] = {}  # index -> estimator names
    pair_names: dict[int, str] = {}
    errors: dict[int, dict[str, str]] = {}
    times: dict[int, dict[str, int]] = {}

    def rows(rb) -> Iterator[tuple[int, int]]:
        """(row number, index on tl) for the rows of a temporal batch that are on tl."""
        if tl is None or tl not in rb.schema.names:
            return
        others = [t for t in _index_names(rb) if t != tl and t not in BUILTIN_TIMELINES]
        other_vals = {t: _ints(rb.column(t)) for t in others}
        for i, ix in enumerate(_ints(rb.column(tl))):
            if ix is None:
                continue
            slot = times.setdefault(ix, {})
            for t in others:
                if other_vals[t][i] is not None:
                    slot[t] = other_vals[t][i]
            yield i, ix

    content = [_entity(L.PAIR_METRICS), _entity(L.PAIR_INFO), _entity(L.error("**"))]
    for ent, is_static, rb in _chunks(p, content, reader):
        cols = rb.schema.names
        if is_static:
            continue
        if ent == L.PAIR_METRICS and _ESTIMATORS in cols:
            metric_cols = [c for c in cols if c not in (_ROW_ID, _ESTIMATORS, *_index_names(rb))]
            data = {c: rb.column(c).to_pylist() for c in [_ESTIMATORS, *metric_cols]}
            for i, ix in rows(rb):
                if data[_ESTIMATORS][i] is None:
                    continue
                names[ix] = list(data[_ESTIMATORS][i])
                values[ix] = {c: [math.nan if x is None else float(x) for x in data[c][i]]
                              for c in metric_cols if data[c][i] is not None}
        elif ent == L.PAIR_INFO and _TEXT in cols:
            col = rb.column(_TEXT).to_pylist()
            for i, ix in rows(rb):
                if col[i]:
                    pair_names[ix] = col[i][0]
        elif ent.startswith(error_prefix) and _LOG_TEXT in cols:
            est = ent[len(error_prefix):]
            col = rb.column(_LOG_TEXT).to_pylist()
            for i, ix in rows(rb):
                if col[i]:
                    msg = col[i][0]
                    prefix = f"{est} failed: "  # how the writer words it
                    errors.setdefault(ix, {})[est] = msg[len(prefix):] if msg.startswith(prefix) else msg

    metrics = sorted({k for per in values.values() for k in per})
    estimators: dict[str, None] = {}
    for ix in sorted(names):
        estimators.update(dict.fromkeys(names[ix]))
    items = []
    for ix in sorted(set(values) | set(pair_names) | set(errors)):
        per_metric = {key: dict(zip(names.get(ix, []), vals)) for key, vals in sorted(values.get(ix, {}).items())}
        items.append(Item(ix, pair_names.get(ix), per_metric, errors.get(ix, {}), times.get(ix, {})))
    return RecordingSummary(
        path=p,
        app_id=rec.application_id,
        recording_id=rec.recording_id,
        timeline=tl,
        timelines=tuple(all_timelines),
        items=tuple(items),
        metrics=tuple(metrics),
        estimators=tuple(estimators),
        has_blueprint=bool(reader.blueprints()),
        entity_paths=tuple(entities),
    )


def _nan_to_none(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None  # JSON has no NaN / Infinity
    if isinstance(x, dict):
        return {k: _nan_to_none(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_nan_to_none(v) for v in x]
    return x


