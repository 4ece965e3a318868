"""Pairs logged one by one into a caller's Rerun stream (:func:`fviz.log_result`, ``index=i``): many pairs of any
sizes in one stream behave in the viewer as an ``eval --full`` recording's pairs do.

- Each pair logs every F's keypoints (their classes differ from pair to pair: no blueprint override, unlike a
  single pair's file) and its arrows even when there are none (:func:`fviz.record.pair_recording.log_pair`, ``many``).
- At each index, what another pair logged and this one did not (an F only some pairs have, an epipole's arrow,
  the reference lines, an estimator's error) is cleared (``rr.Clear`` at that index of ``pair``): at pair i only
  pair i's entities are live, whatever order the pairs come in.
- The blueprint: while the stream holds one pair, inspect's (opens on ``probe``); from a second index on, every F
  of its pairs, the views framing the largest pair (Rerun keeps one layout per recording, not one per time: a
  smaller pair is drawn from the top left of the same views), opening on ``pair``. Sent again only when it changes;
  the viewer shows the last sent (:func:`sent_last` finds it in a file).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fviz.record import layout as L


@dataclass
class _Logged:
    """What fviz logged into one stream: per index the entity paths (temporal) of its pair and those cleared
    there, the image sizes; every F's name in order; the key of the blueprint last sent."""

    paths: dict[int, set[str]] = field(default_factory=dict)
    every: set[str] = field(default_factory=set)
    cleared: dict[int, set[str]] = field(default_factory=dict)
    sizes: dict[int, tuple] = field(default_factory=dict)
    names: dict[str, None] = field(default_factory=dict)
    sent: Any = None


_streams: "weakref.WeakKeyDictionary[Any, _Logged]" = weakref.WeakKeyDictionary()


class Noting:
    """A stream whose ``log`` notes the entity paths logged on its timelines (static ones are not a pair's)."""

    def __init__(self, rec):
        self.rec, self.paths = rec, set()

    def log(self, path: str, *args, static: bool = False, **kwargs) -> None:
        if not static:
            self.paths.add(path.strip("/"))
        self.rec.log(path, *args, static=static, **kwargs)

    def __getattr__(self, name: str):
        return getattr(self.rec, name)


def log_pair_into(rec, pair, result, lines: int, probe: int, probe_by: str | None, index: int, blueprint: bool,
                  redraw: bool = False, legend: bool = True) -> None:
    """One pair at ``pair`` = index of ``rec`` (see the module docstring), the other pairs' entities cleared there;
    the residual legend too unless ``legend`` is False. ``redraw``: the same pair again, its matches edited
    (:mod:`fviz.editing`): its images stay; what it drew before and not now (a failed estimator's lines) is cleared."""
    import rerun as rr

    from fviz.record.pair_recording import log_pair_recording
    from fviz.record.pair_text import suspect_notice

    state = _streams.setdefault(rec, _Logged())
    noting = Noting(rec)
    redraw = redraw and index in state.paths
    log_pair_recording(noting, pair, result, lines, probe, probe_by, index, many=True, redraw=redraw, legend=legend)
    if redraw:
        kept = {L.image(v) for v in L.VIEWS} & state.paths[index]
        for path in sorted(state.paths[index] - noting.paths - kept):
            rec.set_time(L.TIMELINE, sequence=index)
            rec.log(path, rr.Clear(recursive=False))
        noting.paths |= kept
    state.paths[index], state.cleared[index] = noting.paths, set()
    state.sizes[index] = (tuple(pair.size_a), tuple(pair.size_b))
    state.names.update(dict.fromkeys(r.name for r in result.estimators))
    _clear_others(rec, state, index)
    rec.set_time(L.TIMELINE, sequence=index)
    if not blueprint:
        return
    many = len(state.sizes) > 1
    sizes = sorted(set(state.sizes.values())) if many else state.sizes[index]
    notice = "" if many else suspect_notice(result.notes)  # a run's suspect pairs say so in their summaries
    key = (tuple(state.names), tuple(sizes), notice, many)
    if key != state.sent:
        rec.send_blueprint(L.blueprint(list(state.names), sizes, single_pair=True, notice=notice, verdict=True,
                                       timeline=L.TIMELINE if many else None))
        state.sent = key


def _clear_others(rec, state: _Logged, index: int) -> None:
    """``rr.Clear`` at ``index`` the paths other pairs logged and this one did not; when this pair brings paths no
    other had, those at every other index too (each path once per index: a run costs O(pairs), not O(pairs^2))."""
    import rerun as rr

    new = state.paths[index] - state.every
    state.every |= state.paths[index]
    for j in sorted(state.paths) if new else [index]:
        gone = state.every - state.paths[j] - state.cleared[j]
        if not gone:
            continue
        rec.set_time(L.PROBE_TIMELINE, sequence=0)
        rec.set_time(L.TIMELINE, sequence=j)
        for path in sorted(gone):
            rec.log(path, rr.Clear(recursive=False))
        state.cleared[j] |= gone


def sent_last(reader) -> Any:
    """The blueprint store of an ``RrdReader`` that was sent last (the one the viewer shows: each send made its own
    active), None when the file has none. ``blueprints()`` lists them by id; the file's order is that of their ids'
    first bytes in it."""
    import mmap

    stores = reader.blueprints()
    if len(stores) < 2:
        return stores[0] if stores else None
    with open(Path(reader.path), "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
        return max(stores, key=lambda s: data.find(s.recording_id.encode()))
