"""What fviz rebuilds from a recording it wrote: the stored blueprint with another tab active (``fviz open --tab``),
its plots' y ranges, the keypoint classes of each estimator's tab, and the pairs a click needs
(:mod:`fviz.interactive`). Read with :mod:`fviz.record.reader`."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from fviz.errors import FvizError
from fviz.record import layout as L
from fviz.record.placement import offset_b
from fviz.record.reader import _blueprint_fields, _chunks, _entity, _ints, column, entity_paths, image_size, open_rrd, text
from fviz.record.summary import read_recording


def recording_blueprint(path: str | Path, active: str | None = None, sizes=None):
    """(application id, the blueprint fviz stores in such a recording) rebuilt from what the file holds (``sizes``:
    the images' to frame where it has none), opening on tab ``active`` (an estimator's name, ``overview``, ``probe``,
    ``metrics``, ``motion``). FvizError naming the tabs there are when there is no such tab."""
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


SUSPECT_BANNER = "**⚠ ground truth suspect**: "  # how a single pair's summary opens when it is (record.pair_text)


def suspect_notice_of(path: str | Path) -> str:
    """The overview's warning of a single pair's recording, from its summary's first line."""
    from fviz.diagnose import GT_SUSPECT_NOTE
    from fviz.record.pair_text import suspect_notice

    first = (text(path, L.SUMMARY) or [""])[0].split("\n", 1)[0]
    return suspect_notice([GT_SUSPECT_NOTE + first.removeprefix(SUSPECT_BANNER)] if first.startswith(SUSPECT_BANNER) else [])


def series_ranges(path: str | Path, paths=None) -> dict[str, tuple | None]:
    """The y ranges of a run's plots (as the writer chose them) from the series the file holds."""
    from fviz.record.run_plots import VALUE_PATHS, ranges_of_values

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


def click_pairs(path: str | Path) -> dict[int, Any]:
    """{pair index: :class:`fviz.record.clickable.PairFs`} of every pair whose images, F's (``pair/fundamental``) and
    matches the recording holds (the ground truth's matches, else the first estimator's); {} for a recording
    written before fviz logged the F's, or without images (eval without --full)."""
    reader = open_rrd(path)
    tl = L.TIMELINE
    fs: dict[int, dict] = {}
    pts: dict[int, dict[str, list]] = {}
    for ent, is_static, rb in _chunks(path, [_entity(L.PAIR_FS), "+ /est/**"], reader):
        if is_static or tl not in rb.schema.names:
            continue
        if ent == L.PAIR_FS:
            fs.update(_fundamentals(rb, tl))
        elif L.matches_owner(ent) and "Points2D:positions" in rb.schema.names:
            for t, p in zip(_ints(rb.column(tl)), rb.column("Points2D:positions").to_pylist()):
                if p is not None:
                    pts.setdefault(t, {})[L.matches_owner(ent)] = p
    out = {}
    for t, v in fs.items():
        ends = pts.get(t, {})
        owner = L.GT if L.GT in ends else next(iter(ends), None)
        if (f := _pair_fs(v, ends[owner] if owner else None)) is not None:
            out[t] = f
    return out


def watch_pairs(path: str | Path) -> dict[str, dict[int, Any]]:
    """{watched pair k: {step: :class:`fviz.record.clickable.PairFs`}} of train.rrd (:func:`fviz.log_training_step`):
    per step the F's of ``watch/{k}/fundamental`` (the ground truth's, the network's, a baseline's), coloured as
    drawn (``layout.watch_colors``), the matches its fixed correspondences (``watch/{k}/points``), root ``watch/{k}``;
    {} for any other recording, or one written before fviz logged those F's."""
    reader = open_rrd(path)
    tl = L.TRAIN_TIMELINE
    fs: dict[str, dict[int, dict]] = {}
    ends: dict[str, list] = {}
    for ent, is_static, rb in _chunks(path, "+ /watch/**", reader):
        name, _, what = ent.removeprefix(L.WATCH + "/").partition("/")
        if is_static or tl not in rb.schema.names:
            continue
        if what == "fundamental":
            fs.setdefault(name, {}).update(_fundamentals(rb, tl))
        elif what == "points" and name not in ends and "Points2D:positions" in rb.schema.names:
            ends[name] = next((p for p in rb.column("Points2D:positions").to_pylist() if p is not None), None)
    c = L.watch_colors()
    out: dict[str, dict[int, Any]] = {}
    for name, steps in fs.items():
        for t, v in sorted(steps.items()):
            colors = {k: {L.GT: c[L.GT], L.NETWORK: c[L.NET]}.get(k, c[L.BASELINE]) for k in v.get("estimators") or ()}
            if (f := _pair_fs(v, ends.get(name), colors, L.watch(name))) is not None:
                out.setdefault(name, {})[t] = f
    return out


def _fundamentals(rb, timeline: str) -> dict[int, dict]:
    """{time: {estimators, F, size_a, size_b}} of a chunk of ``pair/fundamental`` (or ``watch/{k}/fundamental``)."""
    cols = {n: rb.column(n).to_pylist() for n in ("estimators", "F", "size_a", "size_b") if n in rb.schema.names}
    return {t: {k: v[i] for k, v in cols.items()} for i, t in enumerate(_ints(rb.column(timeline)))}


def _pair_fs(v: dict, ends, colors: dict | None = None, root: str = ""):
    """A :class:`fviz.record.clickable.PairFs` of one row of :func:`_fundamentals` and its match ends (2N, 2) as drawn
    (b's shifted by ``offset_b``), None without F's."""
    import numpy as np

    from fviz.record.clickable import PairFs

    if len(v) < 4 or not v["estimators"]:
        return None
    xy = np.asarray(ends if ends is not None else np.zeros((0, 2)), float).reshape(-1, 2)
    size_a, n = tuple(int(s) for s in v["size_a"]), len(xy) // 2
    return PairFs(list(v["estimators"]), np.asarray(v["F"], float).reshape(-1, 3, 3), size_a, tuple(int(s) for s in v["size_b"]),
                  xy[:n], xy[n:] - offset_b(size_a), colors or {}, root)
