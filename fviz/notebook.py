"""Click a point, see its lines, in a Jupyter notebook (Rerun's notebook viewer, ``rerun-sdk[notebook]``).

>>> import fviz.notebook
>>> v = fviz.notebook.show(pair, result)          # a pair evaluated with fviz.inspect_pair
>>> v = fviz.notebook.open("runs/x/eval.rrd")     # any fviz recording with images (inspect, eval --full, train.rrd)

Then click a keypoint, or any pixel, of either image: the other image shows that point's epipolar line under
the ground truth and every estimator, each in its colour, and (a keypoint) the match's partner with its
residual under each F; ``v.last`` is that :class:`fviz.interactive.Click`. A second click replaces the first;
on a run the click applies to the pair at the time cursor. The viewer sends each click as a
``SelectionChangeEvent`` (``docs/interactive.md``); :meth:`ClickViewer.handle` takes one (or its JSON) too, and
:meth:`ClickViewer.click` clicks a pixel from Python (the same point in a viewer of a re-estimated result).

Edit the matches (a viewer of :func:`show`): ``v.exclude()`` drops the match last clicked (or ``v.exclude([3, 17])``),
``v.exclude_above(2.0, under="gt")``, ``v.exclude_box("a", (x0, y0), (x1, y1))``, ``v.set("magsac", threshold=3)``,
``v.restore()``, ``v.reset()``: each re-runs every estimator on the matches kept and redraws lines, epipoles, residual
colours, metrics and verdict (``v.result``); ``v.export("edited/")`` writes the match set and the new F's.

Size: the widget (rerun-notebook 0.41) takes ``width``/``height`` in px (below 200 raised to 200) or "auto":
width "auto" is 100% of the cell, height "auto" follows the width at 16:9. The default is both "auto": the
viewer fills the cell's width at any window size (a fixed size overflows a narrow cell or wastes a wide one).

Offline (no access to app.rerun.io, where the widget's JavaScript is fetched from by default), set
``RERUN_NOTEBOOK_ASSET=inline`` before importing rerun.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


class ClickViewer:
    """A ``rerun.notebook.Viewer`` whose clicks draw epipolar lines (shown when it is a cell's result).

    viewer: the ``rerun.notebook.Viewer``; rec: the RecordingStream feeding it (clicks are logged there);
    session: the :class:`fviz.interactive.ClickSession`."""

    def __init__(self, viewer, rec, session, edits=None):
        self.viewer, self.rec, self.session, self.edits = viewer, rec, session, edits
        viewer.on_event(self.handle)

    def _edits(self):
        if self.edits is None:
            raise ValueError("this viewer's pair cannot be edited: show a result of fviz.inspect_pair with fviz.notebook.show")
        return self.edits

    def _edited(self, result):
        self.rec.flush()
        return result

    @property
    def result(self):
        """The pair's result as last (re-)estimated (:class:`fviz.evaluate.PairResult`)."""
        return self._edits().result

    def exclude(self, matches=None):
        """Exclude ``matches`` (match numbers, as the click labels show them; default: the match last clicked),
        re-estimate every F and redraw -> the new result."""
        if matches is None:
            if self.last is None or self.last.match is None:
                raise ValueError("no match clicked: click a keypoint first, or give the match numbers")
            matches = [self.last.match]
        return self._edited(self._edits().exclude(matches))

    def exclude_above(self, px: float, under: str | None = None):
        """Exclude every match whose SED under F ``under`` (default the ground truth) is above ``px``."""
        return self._edited(self._edits().exclude_above(px, under))

    def exclude_box(self, view: str, corner, other_corner):
        """Exclude the matches whose end in image ``view`` lies in the box of two corners (x, y)."""
        return self._edited(self._edits().exclude_box(view, corner, other_corner))

    def restore(self, matches=None):
        """Restore ``matches`` (default: every excluded one)."""
        return self._edited(self._edits().restore(matches))

    def set(self, estimator: str, threshold: float | None = None, max_iters: int | None = None):
        """Another inlier threshold (px) or iteration cap for a robust estimator."""
        return self._edited(self._edits().set(estimator, threshold, max_iters))

    def reset(self):
        """Every match back, every setting as first evaluated."""
        return self._edited(self._edits().reset())

    def export(self, folder):
        """The edited matches (hloc h5 and text) and the new F's into ``folder`` (:meth:`fviz.editing.EditSession.export`)."""
        return self._edits().export(folder)

    def handle(self, event):
        """One viewer event (a ``rerun.notebook`` event, or the JSON string the widget sends) -> the Click it
        made, or None."""
        if isinstance(event, str):
            from fviz.rerun_compat import viewer_event_from_json

            event = viewer_event_from_json(event)
        c = self.session.on_event(event)
        if c is not None:
            self.rec.flush()
        return c

    def click(self, view: str, x: float, y: float):
        """Click pixel (x, y) of image ``view`` ("a" or "b") of the pair at the time cursor (train.rrd: of the watched
        pair last clicked, else the first), as the viewer does (snapped to a match end within reach) -> the
        :class:`fviz.interactive.Click` drawn, None off the image."""
        from fviz.record import layout as L
        from fviz.record.placement import offset_b

        if view not in L.VIEWS:
            raise ValueError(f"view: 'a' or 'b', got {view!r}")
        fs = self.session.current()
        shift = offset_b(fs.size_a) if fs is not None and view == "b" else 0.0
        entity = fs.path(L.image(view)) if fs is not None else L.image(view)
        c = self.session.select(entity, [*(np.asarray([x, y], float) + shift), 0.0])
        if c is not None:
            self.rec.flush()
        return c

    @property
    def last(self):
        return self.session.last

    def display(self) -> None:
        self.viewer.display()

    def _ipython_display_(self) -> None:
        self.viewer.display()


def _viewer(rec, width, height):
    from rerun.notebook import Viewer

    return Viewer(recording=rec, width=width, height=height)


def show(pair, result, width: int | str = "auto", height: int | str = "auto", n_lines: int = 30) -> ClickViewer:
    """A pair (:class:`fviz.data.pair.Pair`) and its evaluation (:class:`fviz.evaluate.PairResult`,
    :func:`fviz.inspect_pair`) in the notebook viewer, fviz's layout, clicks wired; as wide as the cell by default
    (see the module docstring)."""
    import uuid

    import rerun as rr

    from fviz.api import log_result
    from fviz.interactive import ClickSession, pair_fs
    from fviz.record import layout as L

    rec = rr.RecordingStream("fviz-notebook", recording_id=str(uuid.uuid4()))
    viewer = _viewer(rec, width, height)
    log_result(rec, pair, result, lines=n_lines)
    rec.flush()  # to the widget now (queued until it is ready), not at the batcher's next tick
    fs = pair_fs(result, pair.size_a, pair.size_b)
    clicks = ClickSession(rec, {0: fs}, stamps=(L.PROBE_TIMELINE,))
    edits = None
    if getattr(result, "_inspected", None) is not None and result.matches is not None:  # inspect_pair's: editable
        from fviz.api import edit

        edits = edit(pair, result, rec, lines=n_lines, clicks=clicks)
    return ClickViewer(viewer, rec, clicks, edits)


def open(path: str | Path, width: int | str = "auto", height: int | str = "auto") -> ClickViewer:  # noqa: A001
    """A recording fviz wrote (inspect, eval --full, triage, train.rrd's watched pairs) in the notebook viewer, clicks
    wired: the file's bytes go to the viewer, the clicks into the same recording (its application and recording id)."""
    from fviz.interactive import session_for
    from fviz.rerun_compat import send_rrd

    session = session_for(path)
    viewer = _viewer(session.rec, width, height)
    send_rrd(viewer, Path(path).read_bytes())
    return ClickViewer(viewer, session.rec, session)
