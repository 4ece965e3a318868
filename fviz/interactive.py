"""Click a point, see its lines: viewer events -> the clicked point's epipolar lines, logged live.

Rerun cannot project a clicked point into the other image by itself (rerun#6553); its viewers report a click
as a selection (``SelectionChangeEvent``) whose item carries the entity, the instance and the clicked position
(see ``docs/interactive.md``). This module turns such a position into what fviz draws:

- :func:`locate`: a position in the root 2D frame (image a at the top, image b below it shifted by
  ``placement.offset_b``) -> the image clicked and the pixel there (fviz convention: pixel centres at integers);
- :func:`click`: that pixel -> the nearest match end within ``SNAP_PX`` (then the match's partner and its SED
  under every F) and the point's epipolar line in the other image under every F (l_b = F x_a, l_a = F^T x_b),
  clipped to the image;
- :func:`log_click`: draws it at ``layout.click(v)`` (rings, lines in each F's colour, the residuals as a label
  and ``layout.CLICK_TEXT``), replacing the previous click;
- :class:`ClickSession`: the events of one viewer (time cursor, selections) -> log_click into a recording
  stream whose bytes go to that viewer (the notebook widget, :mod:`fviz.web`); :class:`WatchSession` the same on
  train.rrd's watched pairs, under the ground truth's, the network's (at each step) and a baseline's F;
- :class:`OnDemand`: a run's pairs (eval.rrd without --full) drawn into that stream when the time cursor reaches
  them (a right-click in a plot), or when their point of compare.rrd's chart is clicked, so that they can be clicked
  too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fviz.geometry import clip_lines, lines_in_a, lines_in_b, symmetric_epipolar_distance
from fviz.record import layout as L
from fviz.record.placement import screen_unit
from fviz.record.clickable import PairFs  # noqa: F401 (re-exported: the public name)
from fviz.record.placement import offset_b
from fviz.record.marks import ring

# Sizes in screen px (times layout.screen_unit: the same on screen for a KITTI frame and a 3072-px photo)
SNAP_PX = 6.0  # a click this close to a match end picks that match
RING_PX = 7.0  # the clicked point's ring and its partner's
LINE_PX, GT_LINE_PX, HALO_PX = 1.5, 2.0, 1.5  # the clicked lines' radii (the static ones: 0.9) and their dark halo's margin
RING_LINE_PX = 1.3
LABEL_OFF_PX = 10.0  # the partner's label box: this far from its ring, on the side clearest of its lines
HALO_COLOR, RING_COLOR = (0, 0, 0), (255, 255, 255)  # the click's rings: white on a dark halo (keypoints are filled dots)


@dataclass
class Click:
    """One click: ``view`` ("a" or "b") and ``point`` (2,) in that image's pixels (snapped to the match end
    when ``match`` is not None); ``partner`` (2,) the match's other end; per F (``names``) ``lines`` (n, 3) in
    the other image, their clipped ``segments`` (n, 2, 2; NaN outside) and ``inside`` (n,), and ``residuals``
    (n,) the match's SED (px; NaN without a match)."""

    view: str
    point: np.ndarray
    match: int | None
    partner: np.ndarray | None
    names: list[str]
    lines: np.ndarray
    segments: np.ndarray
    inside: np.ndarray
    residuals: np.ndarray

    @property
    def other(self) -> str:
        return "b" if self.view == "a" else "a"


def _within(p: np.ndarray, size: tuple[int, int]) -> bool:
    return bool(-0.5 <= p[0] <= size[0] - 0.5 and -0.5 <= p[1] <= size[1] - 0.5)


def locate(position, size_a: tuple[int, int], size_b: tuple[int, int]) -> tuple[str, np.ndarray] | None:
    """A position in the root 2D frame ((2,) or (3,)) -> (view, (2,) pixel in that image), None off both
    images (the gap between them, the caption below b)."""
    p = np.asarray(position, float)[:2]
    if _within(p, size_a):
        return "a", p
    q = p - offset_b(size_a)
    return ("b", q) if _within(q, size_b) else None


def nearest_match(fs: PairFs, view: str, point: np.ndarray, radius: float) -> int | None:
    """Index of the match whose end in ``view`` is nearest ``point`` (2,), if within ``radius`` px."""
    ends = fs.x_a if view == "a" else fs.x_b
    if not len(ends):
        return None
    d = np.linalg.norm(ends - point, axis=1)
    j = int(np.argmin(d))
    return j if d[j] <= radius else None


def click(fs: PairFs, view: str, point, match: int | None = None, snap: bool = True) -> Click:
    """The click at ``point`` (2,) of image ``view``: ``match`` given (a keypoint's instance) or, with ``snap``,
    the nearest match end within SNAP_PX; the point's lines in the other image under every F."""
    point = np.asarray(point, float)[:2]
    if match is None and snap:
        match = nearest_match(fs, view, point, SNAP_PX * screen_unit(fs.size_a))
    partner = None
    residuals = np.full(len(fs.names), np.nan)
    if match is not None:
        xa, xb = fs.x_a[match], fs.x_b[match]
        point, partner = (xa, xb) if view == "a" else (xb, xa)
        residuals = np.array([symmetric_epipolar_distance(F, xa[None], xb[None])[0] for F in fs.F])
    lines = np.concatenate([(lines_in_b if view == "a" else lines_in_a)(F, point[None]) for F in fs.F]) \
        if len(fs.F) else np.zeros((0, 3))
    other = fs.size("b" if view == "a" else "a")
    segments, inside = clip_lines(lines, *other)
    return Click(view, point, match, partner, list(fs.names), lines, segments, inside, residuals)


def click_at(fs: PairFs, position, entity_path: str | None = None, instance_id: int | None = None) -> Click | None:
    """A selection -> the click, None when it is on neither image. ``position`` (root frame; what Rerun 0.41
    reports for a click in a 2D view) is located and snapped to the nearest match end. A selected match end
    (``entity_path`` a ``layout.matches`` path and ``instance_id`` i: a's end of match i for i < N, b's of match
    i - N) is taken when there is no position, or when it lies within reach of it: Rerun reports the entity
    hovered in the previous frame, which on a slow frame is not the one under the click (the position is)."""
    n = len(fs.x_a)
    picked = None
    if entity_path is not None and fs.ends(entity_path) and instance_id is not None and 0 <= instance_id < 2 * n:
        j = instance_id % n
        view = "a" if instance_id < n else "b"
        picked = view, j, (fs.x_a[j] if view == "a" else fs.x_b[j])
    if position is not None:
        found = locate(position, fs.size_a, fs.size_b)
        if found is None:
            return None
        if picked is None or picked[0] != found[0] or np.linalg.norm(picked[2] - found[1]) > SNAP_PX * screen_unit(fs.size_a):
            return click(fs, *found)
    return None if picked is None else click(fs, picked[0], picked[2], match=picked[1])


def click_text(c: Click) -> str:
    """Markdown: the point, the match and partner, and per F its residual (SED px)."""
    head = f"**click** in image {c.view} at ({c.point[0]:.1f}, {c.point[1]:.1f})"
    if c.match is None:
        return head + " (no match end within reach): its epipolar line in image " + c.other + " under every F."
    rows = [f"| {n} | {r:.2f} |" for n, r in zip(c.names, c.residuals)]
    return "\n".join([head + f": match {c.match}, partner in {c.other} at ({c.partner[0]:.1f}, {c.partner[1]:.1f})",
                      "", "| F | SED px |", "|---|--:|", *rows])


def click_label(c: Click) -> str:
    """The label beside the partner (or the clicked point): one line per F with its residual."""
    if c.match is None:
        return f"({c.point[0]:.0f}, {c.point[1]:.0f})"
    return "\n".join([f"match {c.match}"] + [f"{n}: {r:.2f} px" for n, r in zip(c.names, c.residuals)])


def click_marks(fs: PairFs, c: Click) -> dict[str, tuple[list, list, list, list]]:
    """Per view: (strips, colours, radii, hover labels) to draw: in the clicked image the point's ring, in the other
    the lines (each F's colour, the ground truth's thickest) and the partner's ring. Rings white; every strip over a
    dark halo of its own (:func:`halo_of`), so that the clicked lines stand apart from the static ones."""
    u = screen_unit(fs.size_a)
    name = "clicked" if c.match is None else f"match {c.match}"
    marks = {c.view: ([ring(c.point, RING_PX * u, 20)], [RING_COLOR], [RING_LINE_PX * u], [name]), c.other: ([], [], [], [])}
    strips, colors, radii, labels = marks[c.other]
    for k, name in enumerate(c.names):
        if c.inside[k]:
            strips.append(c.segments[k])
            colors.append(fs.colors[name])
            radii.append((GT_LINE_PX if name == L.GT else LINE_PX) * u)
            labels.append(name if c.match is None else f"{name}: {c.residuals[k]:.2f} px")
    if c.partner is not None:
        strips.append(ring(c.partner, RING_PX * u, 20))
        colors.append(RING_COLOR)
        radii.append(RING_LINE_PX * u)
        labels.append(f"match {c.match}")
    return marks


def halo_of(radii: list, unit: float) -> list:
    """The dark halo's radii under strips of ``radii`` (HALO_PX screen px wider on each side)."""
    return [r + HALO_PX * unit for r in radii]


LABEL_CHAR_PX, LABEL_ROW_PX = 7.0, 16.0  # Rerun's label text: width of a character, height of a row (screen px)


def label_anchor(fs: PairFs, c: Click, text: str) -> tuple[str, np.ndarray]:
    """(view, (2,) point in that image) where the click's label ``text`` goes: Rerun draws it as a box below the
    point, centred. The box is put LABEL_OFF_PX screen px from the partner (or the clicked point), on whichever side
    (either way along its first line's normal, or a diagonal) leaves it clearest of the lines drawn there and of the
    partner, inside the image."""
    u = screen_unit(fs.size_a)
    where, at = (c.other, c.partner) if c.partner is not None else (c.view, c.point)
    w, h = fs.size(where)
    rows = text.split("\n")
    half = 0.5 * u * np.array([LABEL_CHAR_PX * max(len(r) for r in rows), LABEL_ROW_PX * len(rows)])  # the box's
    lines = c.lines[np.asarray(c.inside, bool)] if where == c.other else np.zeros((0, 3))
    normal = lines[0, :2] / max(np.linalg.norm(lines[0, :2]), 1e-12) if len(lines) else np.array([0.7071, -0.7071])
    sides = [normal, -normal, *(np.array(d) / np.sqrt(2) for d in ((1, 1), (1, -1), (-1, 1), (-1, -1)))]
    best, score = at, -np.inf
    for d in sides:
        centre = at + d * ((RING_PX + LABEL_OFF_PX) * u + np.abs(d) @ half)
        centre = np.clip(centre, half, [w - 1.0, h - 1.0] - half)
        ab = lines[:, :2] / np.linalg.norm(lines[:, :2], axis=1, keepdims=True) if len(lines) else np.zeros((0, 2))
        clear = (np.abs(ab @ centre + lines[:, 2] / np.linalg.norm(lines[:, :2], axis=1)) - np.abs(ab) @ half) if len(lines) else []
        own = np.max(np.abs(centre - at) - half)  # the partner outside the box
        value = min(own, *clear) if len(clear) else own
        if value > score:
            best, score = centre - [0.0, half[1]], value
    return where, best


def log_click(rec, fs: PairFs, c: Click) -> None:
    """Draw ``c`` at ``layout.click(v)`` of both views over its halo (``layout.click_halo(v)``), the residual table
    beside the partner off its lines (or the clicked pixel's coordinates beside it), and ``layout.CLICK_TEXT``, at the
    recording's current time, replacing the previous click (same paths, same time: the later row wins); all under the
    pair's root (``fs.path``)."""
    import rerun as rr

    u = screen_unit(fs.size_a)
    text = click_label(c)
    where, anchor = label_anchor(fs, c, text)
    for view, (strips, colors, radii, labels) in click_marks(fs, c).items():
        rec.log(fs.path(L.click_halo(view)), rr.LineStrips2D(strips, colors=[HALO_COLOR] * len(strips),
                                                             radii=halo_of(radii, u), draw_order=48.0))
        rec.log(fs.path(L.click(view)), rr.LineStrips2D(strips, colors=colors, radii=radii, labels=labels,
                                                        show_labels=False, draw_order=49.0))
        if view == where:
            rec.log(fs.path(L.click_label(view)), rr.Points2D([anchor], radii=0.5, colors=[RING_COLOR], labels=[text],
                                                              show_labels=True, draw_order=50.0))
        else:
            rec.log(fs.path(L.click_label(view)), rr.Clear(recursive=False))
    rec.log(fs.path(L.CLICK_TEXT), rr.TextDocument(click_text(c), media_type="text/markdown"))


def clear_click(rec) -> None:
    """Remove the click's marks at the current time (a pair not clicked yet)."""
    import rerun as rr

    for view in L.VIEWS:
        rec.log(L.click(view), rr.Clear(recursive=True))
    rec.log(L.CLICK_TEXT, rr.Clear(recursive=False))


class ClickSession:
    """One viewer's events -> clicks logged into ``rec`` (a RecordingStream with the viewed recording's
    application and recording id, whose bytes go to that viewer).

    pairs: {pair index: PairFs} (:func:`fviz.record.rebuild.click_pairs`, or one pair: {0: ...});
    stamps: other timelines the recording's pair data sits at 0 on (``probe`` for inspect), so that the click
    shows whichever timeline the viewer is on. The time cursor on ``pair`` (TimeUpdateEvent,
    TimelineChangeEvent) picks the pair; on another timeline the last pair seen (the only one, for inspect)."""

    def __init__(self, rec, pairs: dict[int, PairFs], stamps: tuple[str, ...] = (), on_demand: "OnDemand | None" = None):
        self.rec, self.pairs, self.stamps = rec, dict(sorted(pairs.items())), stamps
        self.timeline = L.TIMELINE
        self.index = next(iter(self.pairs), None)
        self.last: Click | None = None
        self.on_demand = on_demand  # a run's pairs drawn when the time cursor reaches them (eval.rrd without --full)
        self.opened_at: float | None = None  # the time the viewer opened on: no pair drawn until the cursor moves
        self.moved = False

    def _at(self, timeline: str, time) -> None:
        self.timeline = timeline
        if timeline == L.TIMELINE and time is not None and self.pairs:
            before = [i for i in self.pairs if i <= float(time)]
            self.index = before[-1] if before else next(iter(self.pairs))

    def _draw(self, time) -> None:
        """The pair at ``time`` on ``pair`` drawn on demand, once the time cursor has left where the viewer opened (the
        viewer reports that time itself: a run's page keeps opening on its plots)."""
        if self.on_demand is None or self.timeline != L.TIMELINE or time is None:
            return
        self.opened_at = float(time) if self.opened_at is None else self.opened_at
        self.moved = self.moved or float(time) != self.opened_at
        if not self.moved:
            return
        index = int(round(float(time)))
        if index not in self.pairs and (fs := self.on_demand.draw(index)) is not None:
            self.pairs = dict(sorted({**self.pairs, index: fs}.items()))
            self._at(self.timeline, time)

    def on_event(self, event) -> Click | None:
        """Handle one ``rerun`` viewer event; -> the click logged, if it was one."""
        kind = getattr(event, "type", None)
        if kind == "timeline_change":
            self._at(event.timeline, event.time)
        elif kind == "time_update":
            self._at(self.timeline, event.time)
            self._draw(event.time)
        elif kind == "selection_change":
            for item in event.items:
                if getattr(item, "type", None) == "entity" and not self._on_chart(item):
                    c = self.select(item.entity_path, item.position, item.instance_id)
                    if c is not None:
                        return c
        return None

    def current(self) -> PairFs | None:
        """The pair at the time cursor (None: none)."""
        return self.pairs.get(self.index) if self.index is not None else None

    def _on_chart(self, item) -> bool:
        """Whether a selection is on a chart (compare.rrd's, inspect's bars: ``layout.COMPARE``), where no image is;
        a pair's point there (``run.pick``, :class:`OnDemand`) is drawn and shown."""
        path = (item.entity_path or "").strip("/")
        index = self.on_demand.run.pick(item.entity_path, item.instance_id, item.position, item.view_name) \
            if self.on_demand is not None else None
        if index is not None and (fs := self.on_demand.show(index)) is not None:
            self.pairs = dict(sorted({**self.pairs, index: fs}.items()))
        if index in self.pairs:
            self.timeline, self.index = L.TIMELINE, index
        return index is not None or path == L.COMPARE or path.startswith(L.COMPARE + "/")

    def select(self, entity_path: str | None, position=None, instance_id: int | None = None) -> Click | None:
        """A selected entity (and position in the root frame, instance) on the current pair -> the click
        logged, None when it is on neither image (or the pair has no F)."""
        fs = self.current()
        if fs is None:
            return None
        c = click_at(fs, position, entity_path.lstrip("/") if entity_path else None, instance_id)
        if c is not None:
            self.log(self.index, fs, c)
            self.last = c
        return c

    def log(self, index: int, fs: PairFs, c: Click) -> None:
        """``c`` at pair ``index``; the next pair's marks cleared, so that the click stays on its own pair."""
        for t in self.stamps:
            self.rec.set_time(t, sequence=0)
        self.rec.set_time(L.TIMELINE, sequence=index)
        log_click(self.rec, fs, c)
        later = [i for i in (*self.pairs, *(self.on_demand.indices if self.on_demand else ())) if i > index]
        if later:
            self.rec.set_time(L.TIMELINE, sequence=min(later))
            clear_click(self.rec)


class WatchSession(ClickSession):
    """A viewer's events on train.rrd (:func:`fviz.log_training_step`) -> clicks logged into ``rec``.

    watched: {pair name k: {step: PairFs}} (:func:`fviz.record.rebuild.watch_pairs`: per step the ground truth's,
    the network's and a baseline's F). The clicked entity (``watch/{k}/...``) picks the pair (else the last one
    clicked), the time cursor on ``step`` its frame (the last at or before it; none seen: the last frame). The click
    is drawn under ``watch/{k}`` at every frame of the pair, each under that step's F's, so that scrubbing ``step``
    shows the point's lines converge; the Click returned (``last``) is the cursor's."""

    def __init__(self, rec, watched: dict[str, dict[int, PairFs]]):
        super().__init__(rec, {})
        self.watched = {k: dict(sorted(f.items())) for k, f in watched.items() if f}
        self.timeline, self.name, self.step = L.TRAIN_TIMELINE, next(iter(self.watched), None), None

    def _at(self, timeline: str, time) -> None:
        self.timeline = timeline
        if timeline == L.TRAIN_TIMELINE and time is not None:
            self.step = float(time)

    def current(self) -> PairFs | None:
        frames = self.watched.get(self.name, {})
        before = [s for s in frames if self.step is None or s <= self.step] or list(frames)[:1]
        return frames[before[-1]] if before else None

    def select(self, entity_path: str | None, position=None, instance_id: int | None = None) -> Click | None:
        path = entity_path.strip("/") if entity_path else None
        name = path.split("/")[1] if path and path.startswith(L.WATCH + "/") and path.count("/") > 1 else None
        self.name = name if name in self.watched else self.name
        fs = self.current()
        c = click_at(fs, position, path, instance_id) if fs is not None else None
        if c is None:
            return None
        for step, f in self.watched[self.name].items():
            self.rec.set_time(L.TRAIN_TIMELINE, sequence=step)
            log_click(self.rec, f, c if f is fs else click(f, c.view, c.point, c.match, snap=False))
        self.last = c
        return c


class OnDemand:
    """A run's pairs drawn into a viewer's stream when its time cursor first reaches them, or when a selection picks
    one (a pair's point of compare.rrd's chart): what ``eval --full`` would have recorded of pair i (images,
    keypoints, lines, epipoles: :func:`fviz.record.writer.log_pair`) at ``pair`` = i, for a recording without it
    (eval.rrd holds the metrics alone, compare.rrd a chart). ``run`` (:mod:`fviz.api.runpairs`): ``indices`` (its
    pairs), ``load(i) -> (Pair, PairResult)`` (:func:`fviz.read_pair`), ``pick(entity_path, instance_id, position,
    view_name) -> i or None``, ``blueprint(sizes, names)``: the layout with views of images of ``sizes``, sent with
    the first pair drawn (and again for a pair of another size).

    Only the pairs drawn carry images: at the next pair of the run (not drawn yet) what pair i drew is cleared, so
    that a pair never shows another's images; what a drawn neighbour lacks is cleared at it too."""

    def __init__(self, rec, run):
        self.rec, self.run, self.indices = rec, run, sorted(run.indices)
        self.drawn: dict[int, set[str]] = {}  # index -> the paths its pair logged
        self.failed: dict[int, str] = {}
        self.sizes: set[tuple] = set()
        self.changed = False  # data logged since the owner last looked (take it with :meth:`take`)
        self.goto: int | None = None  # a pair picked: the viewer's time cursor to move there (:meth:`take`)
        self.error: str | None = None  # why the last pair to draw could not be read

    def take(self) -> tuple[bool, int | None, str | None]:
        """Since the last call: (whether data was logged, the pair to move the viewer's time cursor to, why a pair
        could not be drawn)."""
        out = self.changed, self.goto, self.error
        self.changed, self.goto, self.error = False, None, None
        return out

    def show(self, index: int) -> PairFs | None:
        """Pair ``index`` drawn (:meth:`draw`) and the viewer to be moved to it, if it could be (else ``error``
        says why)."""
        fs = self.draw(index)
        self.goto = index if index in self.drawn else None
        self.error = self.failed.get(index) if self.goto is None else None
        return fs

    def draw(self, index: int) -> PairFs | None:
        """Pair ``index`` drawn (once): its :class:`PairFs`; None when it is not the run's or cannot be read."""
        import rerun as rr

        from fviz.errors import FvizError
        from fviz.record.stream_pairs import Noting
        from fviz.record.pair_recording import log_pair
        from fviz.record.run_plots import log_static

        if index not in self.indices or index in self.drawn or index in self.failed:
            return None
        try:
            pair, result = self.run.load(index)
        except FvizError as exc:  # the record says why (its summary is in eval.rrd already)
            self.failed[index] = self.error = str(exc)
            return None
        if not self.drawn:
            log_static(self.rec, [r.name for r in result.estimators])  # the residual classes' colours
        noting = Noting(self.rec)
        log_pair(noting, index, pair, result, single_pair=False)
        self.drawn[index] = {p for p in noting.paths if not _in_every_pair(p)}
        clear_click(self.rec)  # at index: another pair's click, from before it
        later = [i for i in self.indices if i > index]
        if later:
            gone = self.drawn[index] - self.drawn.get(later[0], set())
            self.rec.set_time(L.TIMELINE, sequence=later[0])
            for path in sorted(gone):
                self.rec.log(path, rr.Clear(recursive=False))
            if later[0] not in self.drawn:
                clear_click(self.rec)
        size = (tuple(pair.size_a), tuple(pair.size_b))
        if size not in self.sizes:
            self.sizes.add(size)
            names = [r.name for r in result.estimators]
            self.rec.send_blueprint(self.run.blueprint(sorted(self.sizes) if len(self.sizes) > 1 else size, names))
        self.rec.set_time(L.TIMELINE, sequence=index)
        self.changed = True
        return pair_fs(result, pair.size_a, pair.size_b)


def _in_every_pair(path: str) -> bool:
    """Whether eval.rrd logs ``path`` at every pair (its text, verdict, metrics, errors, series): never cleared."""
    from fviz.record.run_plots import SERIES_PATHS

    return path in SERIES_PATHS or path in (L.VERDICT, L.PAIR_INFO, L.SUMMARY, L.PAIR_METRICS) or path.startswith(L.error(""))


def session_for(path, rec=None):
    """A :class:`ClickSession` on the recording at ``path``: a new RecordingStream with the file's application
    and recording id (the clicks land in the recording the viewer shows) unless ``rec`` is given."""
    import rerun as rr

    from fviz.record.reader import store_ids, timelines
    from fviz.record.rebuild import click_pairs, watch_pairs

    app_id, rec_id = store_ids(path)
    rec = rec or rr.RecordingStream(app_id, recording_id=rec_id, send_properties=False)
    return session_of(rec, click_pairs(path), timelines(path), watch_pairs(path))


def session_of(rec, pairs: dict, timelines, watched: dict) -> ClickSession:
    """The session of a recording holding ``pairs`` (:func:`fviz.record.rebuild.click_pairs`) or, train.rrd, ``watched``
    pairs (:func:`fviz.record.rebuild.watch_pairs`; when it has no others); ``timelines``: the recording's."""
    if watched and not pairs:
        return WatchSession(rec, watched)
    return ClickSession(rec, pairs, tuple(t for t in timelines if t == L.PROBE_TIMELINE))


def pair_fs(result, size_a: tuple[int, int], size_b: tuple[int, int]) -> PairFs:
    """The :class:`PairFs` of an evaluated pair (:class:`fviz.evaluate.PairResult`; failed estimators left
    out), as :func:`fviz.record.pair_recording.log_fundamentals` stores it."""
    ok = [r for r in result.estimators if not r.error and r.F is not None]
    m = result.matches
    x_a, x_b = (np.zeros((0, 2)), np.zeros((0, 2))) if m is None else (m.x_a, m.x_b)
    return PairFs([r.name for r in ok], np.array([r.F for r in ok], float).reshape(-1, 3, 3), size_a, size_b, x_a, x_b)
