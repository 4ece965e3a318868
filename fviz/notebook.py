"""Click a point, see its lines, in a Jupyter notebook (Rerun's notebook viewer, ``rerun-sdk[notebook]``).

>>> import fviz.notebook
>>> v = fviz.notebook.show(pair, result)          # a pair evaluated with fviz.inspect_pair
>>> v = fviz.notebook.open("runs/x/eval.rrd")     # any fviz recording with images (inspect, eval --full)

Then click a keypoint, or any pixel, of either image: the other image shows that point's epipolar line under
the ground truth and every estimator, each in its colour, and (a keypoint) the match's partner with its
residual under each F; ``v.last`` is that :class:`fviz.interactive.Click`. A second click replaces the first;
on a run the click applies to the pair at the time cursor. The viewer sends each click as a
``SelectionChangeEvent`` (``docs/interactive.md``); :meth:`ClickViewer.handle` takes one (or its JSON) too, and
:meth:`ClickViewer.click` clicks a pixel from Python (the same point in a viewer of a re-estimated result).

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

    def __init__(self, viewer, rec, session):
        self.viewer, self.rec, self.session = viewer, rec, session
        viewer.on_event(self.handle)

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
        """Click pixel (x, y) of image ``view`` ("a" or "b") of the pair at the time cursor, as the viewer does
        (snapped to a match end within reach) -> the :class:`fviz.interactive.Click` drawn, None off the image."""
        from fviz.record import layout as L
        from fviz.record.placement import offset_b

        if view not in L.VIEWS:
            raise ValueError(f"view: 'a' or 'b', got {view!r}")
        fs = self.session.pairs.get(self.session.index)
        shift = offset_b(fs.size_a) if fs is not None and view == "b" else 0.0
        c = self.session.select(L.image(view), [*(np.asarray([x, y], float) + shift), 0.0])
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
    return ClickViewer(viewer, rec, ClickSession(rec, {0: fs}, stamps=(L.PROBE_TIMELINE,)))


def open(path: str | Path, width: int | str = "auto", height: int | str = "auto") -> ClickViewer:  # noqa: A001
    """A recording fviz wrote (inspect, eval --full, triage) in the notebook viewer, clicks wired: the file's
    bytes go to the viewer, the clicks into the same recording (its application and recording id)."""
    from fviz.interactive import session_for
    from fviz.rerun_compat import send_rrd

    session = session_for(path)
    viewer = _viewer(session.rec, width, height)
    send_rrd(viewer, Path(path).read_bytes())
    return ClickViewer(viewer, session.rec, session)
