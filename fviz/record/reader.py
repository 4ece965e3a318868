"""Read fviz recordings back, low level: open a file, its chunks, an entity's columns and texts, its timelines,
store ids and stored blueprint. What is built from them: :mod:`fviz.record.summary` (what ``fviz summary`` prints)
and :mod:`fviz.record.rebuild` (the blueprint, plot ranges and click pairs rebuilt from a file).

Works on any fviz ``.rrd`` (``inspect``, ``eval``, ``triage``) and on any index timeline: a recording's main
timeline is ``rank`` if present, else ``pair``, else the first other sequence timeline (:func:`main_timeline`).

Every function takes a path and re-reads the file (pure: no caches, no state). A missing file, a file that
is not an RRD, or one cut mid-write (no footer, or a frame running past the end) raises
:class:`fviz.errors.FvizError` with a one-line message naming the file.

Entity paths are given and returned as in :mod:`fviz.record.layout` (``a/image``, ``metrics/epi_abs``;
a leading ``/`` is accepted); the root entity is ``/``.
"""

from __future__ import annotations

import warnings
import weakref
from pathlib import Path
from typing import Any, Iterator, NamedTuple

from fviz.errors import FvizError
from fviz.record import layout as L

# Timelines Rerun adds by itself, and the probe's steps within one pair: never an item index.
BUILTIN_TIMELINES = ("log_time", "log_tick", L.PROBE_TIMELINE)
# Main timeline, by preference (triage ranks pairs that also carry their ``pair`` index).
PREFERRED_TIMELINES = ("rank", L.TIMELINE)

_ROW_ID = "rerun.controls.RowId"
_TEXT = "TextDocument:text"
_LOG_TEXT = "TextLog:text"


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


def store_ids(path: str | Path) -> tuple[str, str]:
    """(application id, recording id) of the recording in the file."""
    s = open_rrd(path).recordings()[0]
    return s.application_id, s.recording_id


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


# --------------------------------------------------------------------------------------------- stored blueprint


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

