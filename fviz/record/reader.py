"""Read fviz recordings back: what ``fviz summary`` prints and what tests check recordings with.

Works on any fviz ``.rrd`` (``inspect``, ``eval``, ``triage``) and on any index timeline: items are the
time indices of the ``pair/info`` and ``pair/metrics`` rows on the recording's main timeline (``rank`` if
present, else ``pair``, else the first other sequence timeline; see :func:`main_timeline`).

Every function takes a path and re-reads the file (pure: no caches, no state). A missing file, a file that
is not an RRD, or one cut mid-write (no footer, or a frame running past the end) raises
:class:`fviz.errors.FvizError` with a one-line message naming the file.

Entity paths are given and returned as in :mod:`fviz.record.layout` (``a/image``, ``metrics/epi_abs``;
a leading ``/`` is accepted); the root entity is ``/``.
"""

from __future__ import annotations

import math
import warnings
import weakref
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterator, NamedTuple

from fviz.errors import FvizError
from fviz.record import layout as L

# Timelines Rerun adds by itself, and the probe's steps within one pair: never an item index.
BUILTIN_TIMELINES = ("log_time", "log_tick", L.PROBE_TIMELINE)
# Main timeline, by preference (triage ranks pairs that also carry their ``pair`` index).
PREFERRED_TIMELINES = ("rank", L.TIMELINE)

_ROW_ID = "rerun.controls.RowId"
_ESTIMATORS = "estimators"  # the names column of ``pair/metrics``
_TEXT = "TextDocument:text"
_LOG_TEXT = "TextLog:text"


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


# --------------------------------------------------------------------------------------------- opening


def _entity(path: str) -> str:
    """Layout spelling -> Rerun's (``a/image`` -> ``/a/image``)."""
    return "/" + path.strip("/")


def _layout(path: str) -> str:
    """Rerun's spelling -> layout's (``/a/image`` -> ``a/image``; the root stays ``/``)."""
    return path.strip("/") or "/"


def _one_line(exc: BaseException) -> str:
    """The exception's message on one line, without the reader's own "Failed to read RRD file at X:"."""
    import re

    text = " ".join(str(exc).split()) or type(exc).__name__
    return re.sub(r"^Failed to read RRD file at .*?: ", "", text)


def open_rrd(path: str | Path):
    """A checked ``rerun.chunk.RrdReader`` on a complete fviz/Rerun file, or FvizError naming it.

    Complete means a footer is present (Rerun 0.41 writes one on close; ``fviz`` writers rename the file
    into place only after that) or, in a file written without one (a single pair), that its last message is
    ``layout.END``: a file cut exactly between two frames would otherwise read as a shorter, silently
    incomplete recording."""
    from rerun.chunk import RrdReader

    p = Path(path)
    if not p.exists():
        raise FvizError(f"{p}: no such recording")
    if not p.is_file():
        raise FvizError(f"{p}: not a file")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # RerunWarning on footer-less files: reported below instead
        try:
            reader = RrdReader(p)
            if not reader.recordings():
                raise FvizError(f"{p}: not a recording (no recording store in the file)")
            contents = _contents(reader)
            if not contents.footer and contents.last != _entity(L.END):
                raise FvizError(f"{p}: truncated recording (no footer and no end mark: cut mid-write?)")
        except FvizError:
            raise
        except Exception as exc:  # ValueError / RuntimeError from the Rust reader: not an RRD, cut, I/O
            msg = _one_line(exc)
            if "exceeds file size" in msg or "unexpected end" in msg.lower() or "eof" in msg.lower():
                raise FvizError(f"{p}: truncated recording (cut mid-write?): {msg}") from None
            raise FvizError(f"{p}: not a readable Rerun recording: {msg}") from None
    return reader


class _Contents(NamedTuple):
    footer: bool  # the file ends with Rerun's footer (its manifest makes ``store()`` possible)
    paths: list[str]  # entity paths, Rerun's spelling
    timelines: list[str]  # index timelines
    last: str | None  # entity of the last chunk in file order (read only for a file without a footer)


_CONTENTS: "weakref.WeakKeyDictionary[Any, _Contents]" = weakref.WeakKeyDictionary()


def _contents(reader) -> _Contents:
    """What the first recording holds: from the footer's manifest or, in a file without one (a single
    pair's: small), from one pass over its chunks. Read once per reader."""
    if reader in _CONTENTS:
        return _CONTENTS[reader]
    try:
        schema = reader.store().schema()
        out = _Contents(True, list(schema.entity_paths()), [ix.name for ix in schema.index_columns()], None)
    except Exception as exc:  # the reader says there is no footer/manifest; anything else is a real error
        msg = _one_line(exc)
        if "footer" not in msg and "manifest" not in msg:
            raise
        paths: dict[str, None] = {}
        names: set[str] = set()
        last = None
        for ch in reader.stream().to_chunks():
            paths[last := ch.entity_path] = None
            names.update(ch.timeline_names)
        out = _Contents(False, list(paths), sorted(names), last)
    _CONTENTS[reader] = out
    return out


def _chunks(path: str | Path, content: str | list[str] | None = None, reader=None) -> Iterator[tuple[str, bool, Any]]:
    """(entity path as in the layout, is_static, pyarrow RecordBatch) of the first recording's chunks
    (only those under ``content``, Rerun entity path filter expressions, when given)."""
    reader = reader or open_rrd(path)
    stream = reader.stream()
    if content is not None:
        stream = stream.filter(content=content)
    try:
        for ch in stream.to_chunks():
            yield _layout(ch.entity_path), ch.is_static, ch.to_record_batch()
    except Exception as exc:
        raise FvizError(f"{Path(path)}: cannot read the recording ({_one_line(exc)})") from None


def _index_names(rb) -> list[str]:
    """Index (timeline) columns of a record batch."""
    out = []
    for f in rb.schema:
        md = f.metadata or {}
        if md.get(b"rerun:kind") == b"index":
            out.append(f.name)
    return out


def _ints(col) -> list[int]:
    """An index column as Python ints (timestamps/durations as integer nanoseconds: pyarrow refuses them)."""
    import pyarrow as pa

    if pa.types.is_timestamp(col.type) or pa.types.is_duration(col.type) or pa.types.is_date(col.type):
        col = col.cast(pa.int64())
    return col.to_pylist()


# --------------------------------------------------------------------------------------------- helpers


def entity_paths(path: str | Path) -> list[str]:
    """Every entity path in the recording, sorted, layout spelling (``["/", "a/image", ...]``)."""
    return sorted({_layout(p) for p in _contents(open_rrd(path)).paths if not p.startswith("/__")})


def timelines(path: str | Path) -> list[str]:
    """Every index timeline in the recording, sorted."""
    return sorted(_contents(open_rrd(path)).timelines)


def main_timeline(names: list[str] | tuple[str, ...]) -> str | None:
    """``rank`` > ``pair`` > the first other non-builtin timeline (sorted) > None."""
    for t in PREFERRED_TIMELINES:
        if t in names:
            return t
    rest = sorted(t for t in names if t not in BUILTIN_TIMELINES)
    return rest[0] if rest else None


def columns(path: str | Path, entity: str) -> list[str]:
    """Column names (components and timelines) of an entity, sorted; FvizError if the entity is absent."""
    names: set[str] = set()
    found = False
    for _, _, rb in _chunks(path, _entity(entity)):
        found = True
        names.update(n for n in rb.schema.names if n != _ROW_ID)
    if not found:
        raise FvizError(f"{Path(path)}: no entity {_layout(entity)!r}")
    return sorted(names)


def column(path: str | Path, entity: str, name: str, timeline: str | None = None) -> list:
    """The values of one column of an entity, as Python objects, one per logged row.

    name: a component column (``"Scalars:scalars"``, ``"TextDocument:text"``, ``"residual_px"``, ...) or a
          timeline (``"pair"``); component values are lists (a row holds a batch).
    Rows: static rows first, then temporal rows ascending on ``timeline`` (default: the recording's main
    timeline; rows not on it keep their logged order at the end). FvizError if the entity or column is
    missing (the message lists the columns there are)."""
    reader = open_rrd(path)
    tl = timeline or main_timeline(_contents(reader).timelines)
    static: list = []
    rows: list[tuple[int, int, Any]] = []  # (has no time, time, value)
    seen_cols: set[str] = set()
    for _, is_static, rb in _chunks(path, _entity(entity), reader):
        seen_cols.update(n for n in rb.schema.names if n != _ROW_ID)
        if name not in rb.schema.names:
            continue
        col = rb.column(name)
        values = _ints(col) if name in _index_names(rb) else col.to_pylist()
        if is_static:
            static.extend(values)
        else:
            times = _ints(rb.column(tl)) if tl in rb.schema.names else [None] * len(values)
            rows.extend((t is None, t or 0, v) for t, v in zip(times, values))
    if not seen_cols:
        raise FvizError(f"{Path(path)}: no entity {_layout(entity)!r}")
    if name not in seen_cols:
        raise FvizError(f"{Path(path)}: entity {_layout(entity)!r} has no column {name!r} "
                        f"(it has {', '.join(sorted(seen_cols))})")
    rows.sort(key=lambda r: (r[0], r[1]))  # stable: logged order within a time
    return static + [v for _, _, v in rows]


def text(path: str | Path, entity: str) -> list[str]:
    """The texts of a TextDocument or TextLog entity (``summary``, ``pair/info``, ``errors/{e}``), in row order."""
    cols = columns(path, entity)
    name = _TEXT if _TEXT in cols else _LOG_TEXT
    return [v[0] if isinstance(v, list) and v else v for v in column(path, entity, name)]


# --------------------------------------------------------------------------------------------- summary


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


def image_size(path: str | Path, view: str) -> tuple[int, int] | None:
    """(width, height) of the first ``{view}/image`` of a recording, None when it holds no image."""
    import cv2
    import numpy as np

    try:
        blobs = column(path, L.image(view), "EncodedImage:blob")
    except FvizError:
        return None
    blob = blobs[0][0] if blobs and isinstance(blobs[0], list) else blobs[0]
    img = cv2.imdecode(np.frombuffer(bytes(blob), np.uint8), cv2.IMREAD_GRAYSCALE)
    return None if img is None else (int(img.shape[1]), int(img.shape[0]))


def recording_blueprint(path: str | Path, active: str | None = None, sizes=None):
    """(application id, the blueprint fviz stores in such a recording) rebuilt from the file (``sizes``: images' to frame
    where it has none), opening on tab ``active`` (an estimator, overview, probe, metrics, motion; else FvizError)."""
    s = read_recording(path)
    many = L.PROBE_TIMELINE in s.timelines and len(s.items) > 1  # pairs logged into one stream (record.stream_pairs)
    sizes = sizes or (sorted({(f.size_a, f.size_b) for f in click_pairs(path).values()}) if many else
                      (image_size(path, "a"), image_size(path, "b")))
    single_pair = L.PROBE_TIMELINE in s.timelines or L.COMPARE in s.entity_paths
    classes = match_classes(path) if single_pair and not many and L.matches(L.GT) in s.entity_paths else None
    ranges = None if single_pair else series_ranges(path, s.entity_paths)
    notice = suspect_notice_of(path) if single_pair and L.SUMMARY in s.entity_paths else ""
    try:
        bp = L.blueprint(list(s.estimators), sizes if None not in sizes else None, single_pair=single_pair,
                         head=L.TRIAGE_TAGS in s.entity_paths, active=active, classes=classes, ranges=ranges,
                         curves=any(p.startswith(L.CURVES + "/") for p in s.entity_paths),
                         run_summary=L.RUN_SUMMARY in s.entity_paths, notice="" if many else notice,
                         verdict=L.VERDICT in s.entity_paths and None not in sizes, timeline=L.TIMELINE if many else None)
    except ValueError as exc:
        raise FvizError(f"--tab {active}: {path} has {exc}") from None
    return s.app_id, bp


SUSPECT_BANNER = "**⚠ ground truth suspect**: "  # how a single pair's summary opens when it is (record.writer)


def suspect_notice_of(path: str | Path) -> str:
    """The overview's warning of a single pair's recording, from its summary's first line."""
    from fviz.diagnose import GT_SUSPECT_NOTE
    from fviz.record.writer import suspect_notice

    first = (text(path, L.SUMMARY) or [""])[0].split("\n", 1)[0]
    return suspect_notice([GT_SUSPECT_NOTE + first.removeprefix(SUSPECT_BANNER)] if first.startswith(SUSPECT_BANNER) else [])


def series_ranges(path: str | Path, paths=None) -> dict[str, tuple | None]:
    """The y ranges of a run's plots (as the writer chose them) from the series the file holds."""
    from fviz.record.writer import VALUE_PATHS, ranges_of_values

    paths = paths if paths is not None else entity_paths(path)
    values: dict[str, dict[str, list[float]]] = {}
    for p in VALUE_PATHS:
        if p not in paths:
            continue
        values[p] = series_values(path, p)
    return ranges_of_values(values)


def series_values(path: str | Path, entity: str) -> dict[str, list[float]]:
    """{series name: its value at each logged time (NaN: none)} of one of a run's plotted entities."""
    per: dict[str, list[float]] = {n: [] for n in series_names(path, entity)}
    try:
        rows = column(path, entity, "Scalars:scalars")
    except FvizError:  # styled, never logged
        rows = []
    for row in rows:
        for n, v in zip(per, row or ()):
            per[n].append(math.nan if v is None else float(v))
    return per


def series_names(path: str | Path, entity: str) -> list[str]:
    """The names of a run's series (drawn as lines or as points), in the order of their values."""
    for style in ("SeriesLines:names", "SeriesPoints:names"):
        try:
            names = next((v for v in column(path, entity, style) if v), None)
        except FvizError:
            names = None
        if names:
            return list(names)
    return []


def _blueprint_fields(reader) -> dict[str, dict[str, Any]]:
    """The stored blueprint: {entity (layout spelling): {component (without its archetype): last value}};
    {} when the file stores none; of several (a stream's pairs, fviz.log_result), the last sent: the one shown."""
    from fviz.record.stream_pairs import sent_last

    fields: dict[str, dict[str, Any]] = {}
    for ch in (reader.stream(store=store).to_chunks() if (store := sent_last(reader)) is not None else []):
        rb = ch.to_record_batch()
        slot = fields.setdefault(_layout(ch.entity_path), {})
        for name in rb.schema.names:
            if name == _ROW_ID or name in _index_names(rb):
                continue
            value = rb.column(name).to_pylist()[-1]
            if value is not None:
                slot[name.split(":")[-1]] = value
    return fields


def match_classes(path: str | Path) -> dict[str, list[int]]:
    """{estimator: class ids of its ``layout.matches``} of the first pair: logged in the recording (runs, and
    the ground truth of a single pair) or, for an estimator of a single pair, the override of its tab."""
    reader = open_rrd(path)
    out: dict[str, list[int]] = {}
    for ent, _, rb in _chunks(path, "/est/**", reader):
        name = L.matches_owner(ent)
        if name is not None and "Points2D:class_ids" in rb.schema.names:
            out.setdefault(name, rb.column("Points2D:class_ids").to_pylist()[0])
    fields = _blueprint_fields(reader)
    for ref, f in fields.items():
        if ref.startswith("view/") and ref.count("/") == 1:
            tag = f"{ref}/ViewContents/overrides/{L.matches(L.GT)}/visualizers/"
            override = next((v for k, v in fields.items() if k.startswith(tag) and "class_ids" in v), None)
            if override is not None:
                out.setdefault((f.get("display_name") or [""])[0], override["class_ids"])
    return out


def blueprint_tabs(path: str | Path) -> dict[str, list[str]]:
    """The stored blueprint's tabs: {tab title: the entity queries of every view in it}, in tab order
    ({} when the file stores no tabbed blueprint)."""
    fields = _blueprint_fields(open_rrd(path))

    def queries(ref: str) -> list[str]:
        f = fields.get(ref, {})
        if ref.startswith("view/"):
            return list(fields.get(f"{ref}/ViewContents", {}).get("query", []))
        return [q for child in f.get("contents", []) for q in queries(child)]

    def title(ref: str) -> str:
        return (fields.get(ref, {}).get("display_name") or [""])[0]

    tabs = next((f for f in fields.values() if f.get("container_kind") == [1]), None)  # 1: Tabs
    return {title(ref): queries(ref) for ref in tabs.get("contents", [])} if tabs else {}


def click_pairs(path: str | Path) -> dict[int, Any]:
    """{pair index: :class:`fviz.record.clickable.PairFs`} of every pair whose images, F's (``pair/fundamental``) and
    matches the recording holds (the ground truth's matches, else the first estimator's); {} for a recording
    written before fviz logged the F's, or without images (eval without --full)."""
    import numpy as np

    from fviz.record.clickable import PairFs

    reader = open_rrd(path)
    tl = L.TIMELINE
    fs: dict[int, dict] = {}
    pts: dict[int, dict[str, list]] = {}
    for ent, is_static, rb in _chunks(path, [_entity(L.PAIR_FS), "+ /est/**"], reader):
        if is_static or tl not in rb.schema.names:
            continue
        times = _ints(rb.column(tl))
        if ent == L.PAIR_FS:
            cols = {n: rb.column(n).to_pylist() for n in ("estimators", "F", "size_a", "size_b") if n in rb.schema.names}
            for i, t in enumerate(times):
                fs[t] = {k: v[i] for k, v in cols.items()}
        elif L.matches_owner(ent) and "Points2D:positions" in rb.schema.names:
            for t, p in zip(times, rb.column("Points2D:positions").to_pylist()):
                if p is not None:
                    pts.setdefault(t, {})[L.matches_owner(ent)] = p
    out = {}
    for t, v in fs.items():
        if len(v) < 4 or not v["estimators"]:
            continue
        ends = pts.get(t, {})
        owner = L.GT if L.GT in ends else next(iter(ends), None)
        xy = np.asarray(ends[owner], float).reshape(-1, 2) if owner else np.zeros((0, 2))
        size_a = tuple(int(s) for s in v["size_a"])
        n = len(xy) // 2
        out[t] = PairFs(list(v["estimators"]), np.asarray(v["F"], float).reshape(-1, 3, 3), size_a, tuple(int(s) for s in v["size_b"]),
                        xy[:n], xy[n:] - L.offset_b(size_a))
    return out


def store_ids(path: str | Path) -> tuple[str, str]:
    """(application id, recording id) of the recording in the file."""
    s = open_rrd(path).recordings()[0]
    return s.application_id, s.recording_id
