"""Edit a pair's matches and see every F again: exclude matches (picked, in a box, or above a residual under some F),
restore them, change a robust estimator's threshold or iteration cap; each edit re-runs every estimator of the pair on
the matches kept and redraws what depends on them (lines, epipoles, residual colours, metrics, verdict, comparison).

:class:`EditSession` holds the pair, its result on every match (``base``) and the edit (``excluded``, ``settings``);
``estimate(keep, settings)`` (:func:`fviz.reestimate`, given by the API) evaluates an edit. With a recording stream it
draws each new result at its pair's index, the excluded matches as grey dots (``layout.EXCLUDED``), and points the
viewer's clicks (:class:`fviz.interactive.ClickSession`) at the new F's. Match numbers are the base result's
throughout (a click's ``match``, :meth:`exclude`, the export), so that they do not shift as matches are excluded.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from fviz.errors import FvizError
from fviz.geometry import symmetric_epipolar_distance
from fviz.record import layout as L
from fviz.record.placement import keypoint_radius, match_points

EXCLUDED_COLOR = (150, 150, 150)
SHOWN_METRICS = ("sed_median", "rot_err_deg", "trans_err_deg", "inlier_ratio")


class EditSession:
    """One pair's match edit.

    pair: the :class:`fviz.Pair`; base: its :class:`fviz.evaluate.PairResult` on every match; estimate(keep (N,) bool
    over base's matches, settings {estimator: {"threshold": px, "max_iters": n}}) -> the PairResult of that edit;
    rec, index: where each result is drawn (None: nowhere); clicks: the viewer's ClickSession, pointed at each new
    result; lines, probe: as :func:`fviz.log_result`'s; legend: draw the residual legend with each result (False: the
    viewer has it from the recording, as fviz's page does)."""

    def __init__(self, pair, base, estimate: Callable[[np.ndarray, dict], Any], rec=None, index: int = 0, clicks=None,
                 lines: int = 30, probe: int = 20, legend: bool = True):
        if base.matches is None:
            raise FvizError("result: it has no matches to edit")
        self.pair, self.base, self.estimate = pair, base, estimate
        self.rec, self.index, self.clicks, self.lines, self.probe, self.legend = rec, index, clicks, lines, probe, legend
        self.excluded = np.zeros(len(base.matches), bool)
        self.settings: dict[str, dict[str, float]] = {}
        self.result = base
        self.box: list[tuple[str, np.ndarray]] | None = None  # a box being drawn (the page): its corners so far

    @property
    def n(self) -> int:
        return len(self.excluded)

    @property
    def kept(self) -> np.ndarray:
        """Indices (into the base result's matches) of the matches kept, in order."""
        return np.flatnonzero(~self.excluded)

    def _indices(self, matches) -> np.ndarray:
        idx = np.atleast_1d(np.asarray(matches))
        if idx.dtype == bool:
            if idx.shape != (self.n,):
                raise FvizError(f"matches: a mask needs {self.n} entries (one per match), got {idx.shape}")
            return np.flatnonzero(idx)
        if idx.size and (not np.issubdtype(idx.dtype, np.integer) or idx.min() < 0 or idx.max() >= self.n):
            raise FvizError(f"matches: indices from 0 to {self.n - 1} expected")
        return idx.astype(int)

    # ------------------------------------------------------------------------------------------- edits

    def exclude(self, matches) -> Any:
        """Exclude ``matches`` (indices into the base result's matches, or a (N,) mask) -> the new result."""
        self.excluded[self._indices(matches)] = True
        return self.apply()

    def restore(self, matches=None) -> Any:
        """Restore ``matches`` (every excluded one when None) -> the new result."""
        if matches is None:
            self.excluded[:] = False
        else:
            self.excluded[self._indices(matches)] = False
        return self.apply()

    def toggle(self, match: int) -> Any:
        """Exclude match ``match``, or restore it when excluded (the page's button on a clicked match)."""
        i = int(self._indices(match)[0])
        self.excluded[i] = not self.excluded[i]
        return self.apply()

    def residuals(self, under: str | None = None) -> np.ndarray:
        """(N,) SED (px) of every base match under the current F named ``under`` (default: the ground truth, else
        the first estimator that did not fail)."""
        ok = [r for r in self.result.estimators if r.F is not None and not r.error]
        if not ok:
            raise FvizError("under: no F to measure residuals with (every estimator failed)")
        names = [r.name for r in ok]
        name = under or (L.GT if L.GT in names else names[0])
        if name not in names:
            raise FvizError(f"under {name!r}: not an F of this pair ({', '.join(names)})")
        m = self.base.matches
        return symmetric_epipolar_distance(self.result.get(name).F, m.x_a, m.x_b)

    def exclude_above(self, px: float, under: str | None = None) -> Any:
        """Exclude every match whose SED under F ``under`` (see :meth:`residuals`) is above ``px``."""
        if not (isinstance(px, (int, float)) and math.isfinite(px) and px >= 0):
            raise FvizError(f"px {px!r}: a residual in pixels >= 0")
        self.excluded |= self.residuals(under) > px
        return self.apply()

    def exclude_box(self, view: str, corner, other_corner) -> Any:
        """Exclude the matches whose end in image ``view`` ("a" or "b") lies in the box of two corners (x, y)."""
        if view not in L.VIEWS:
            raise FvizError(f"view {view!r}: 'a' or 'b'")
        lo, hi = np.minimum(corner, other_corner), np.maximum(corner, other_corner)
        ends = self.base.matches.x_a if view == "a" else self.base.matches.x_b
        self.excluded |= np.all((ends >= lo) & (ends <= hi), axis=1)
        return self.apply()

    def start_box(self) -> None:
        """The next two clicks in one image (:meth:`corner`) are a box's corners (the page's "exclude in a box")."""
        self.box = []

    def corner(self, view: str, point) -> Any | None:
        """One corner of the box being drawn -> the new result once the second corner is given, else None. A corner
        in the other image starts the box again."""
        first = self.box[0] if self.box else None
        self.box = [(view, np.asarray(point, float)[:2])]
        if first is None or first[0] != view:
            return None
        self.box = None
        return self.exclude_box(view, first[1], point)

    def set(self, estimator: str, threshold: float | None = None, max_iters: int | None = None) -> Any:
        """Another inlier threshold (px) or iteration cap for ``estimator`` -> the new result."""
        s = dict(self.settings.get(estimator, {}))
        if threshold is not None:
            s["threshold"] = float(threshold)
        if max_iters is not None:
            s["max_iters"] = int(max_iters)
        previous = self.settings.get(estimator)
        self.settings[estimator] = s
        try:
            return self.apply()
        except FvizError:
            self.settings.pop(estimator) if previous is None else self.settings.update({estimator: previous})
            raise

    def reset(self) -> Any:
        """Every match back, every setting as first evaluated."""
        self.excluded[:] = False
        self.settings.clear()
        return self.apply()

    def apply(self) -> Any:
        """Evaluate the edit (the base result itself when nothing is edited) and draw it."""
        edited = self.excluded.any() or any(self.settings.values())
        self.result = self.estimate(~self.excluded, self.settings) if edited else self.base
        self.draw()
        return self.result

    # ------------------------------------------------------------------------------------------- drawing

    def draw(self) -> None:
        """The current result at ``index`` of ``rec`` (its pair's entities replaced), the excluded matches as grey
        crosses, and the viewer's clicks pointed at the new F's (the last one drawn again under them)."""
        if self.clicks is not None:
            from fviz.interactive import click, pair_fs

            fs = pair_fs(self.result, self.pair.size_a, self.pair.size_b)
            fs.x_a, fs.x_b = self.base.matches.x_a, self.base.matches.x_b  # clicks name the base's match numbers
            self.clicks.pairs[self.index] = fs
            c = self.clicks.last
            if c is not None and self.clicks.index == self.index:  # its lines and residuals were the old F's
                self.clicks.last = click(fs, c.view, c.point, match=c.match, snap=False)
                self.clicks.log(self.index, fs, self.clicks.last)
        if self.rec is None:
            return
        import rerun as rr

        from fviz.record.stream_pairs import log_pair_into

        log_pair_into(self.rec, self.pair, self.result, self.lines, self.probe, None, self.index, True, redraw=True,
                      legend=self.legend)
        m, out = self.base.matches, np.flatnonzero(self.excluded)
        self.rec.set_time(L.PROBE_TIMELINE, sequence=0)  # the probe's walk left it at its last step: unseen before it
        if len(out):
            labels = [f"match {i} (excluded)" for i in out] * 2
            self.rec.log(L.EXCLUDED, rr.Points2D(match_points(m.x_a[out], m.x_b[out], self.pair.size_a), colors=EXCLUDED_COLOR,
                                                 radii=1.5 * keypoint_radius(self.pair.size_a), labels=labels,
                                                 show_labels=False, draw_order=45.0))
        else:
            self.rec.log(L.EXCLUDED, rr.Clear(recursive=False))

    # ------------------------------------------------------------------------------------------- reading

    def status(self) -> dict[str, Any]:
        """What the page shows: matches kept and excluded, per F its figures (SHOWN_METRICS) and error, the
        verdict, the robust estimators' settings."""
        r = self.result
        rows = {e.name: {"error": e.error, **{k: _num(e.metrics.get(k)) for k in SHOWN_METRICS}} for e in r.estimators}
        return {"matches": self.n, "excluded": int(self.excluded.sum()), "kept": self.n - int(self.excluded.sum()),
                "excluded_matches": np.flatnonzero(self.excluded).tolist(),
                "estimators": rows, "verdict": None if r.verdict is None else r.verdict.line,
                "settings": self.settings}

    def export(self, folder: str | Path) -> dict[str, Path]:
        """The edited match set and the new F's into ``folder``: hloc's ``features.h5`` + ``matches.h5`` (read back
        by ``--matches folder/matches.h5``), ``matches.txt`` (``x_a y_a x_b y_b [score]``, the base's match number in
        a comment) and ``F.json`` (every F by name, the excluded match numbers, the settings). -> the paths."""
        from fviz.atomic import write_text
        from fviz.data.hloc import write_matches

        folder = Path(folder)
        m, keep = self.base.matches, self.kept
        scores = None if m.scores is None else m.scores[keep]
        features, matches = write_matches(folder, self.pair, m.x_a[keep], m.x_b[keep], scores)
        rows = [f"{xa[0]:.4f} {xa[1]:.4f} {xb[0]:.4f} {xb[1]:.4f}" + ("" if scores is None else f" {scores[j]:.6g}")
                for j, (xa, xb) in enumerate(zip(m.x_a[keep], m.x_b[keep]))]
        head = (f"# {self.pair.id.name}: {len(keep)} of {self.n} matches, edited in fviz (x_a y_a x_b y_b"
                f"{'' if scores is None else ' score'}; pixel centres at integers)")
        text = write_text(folder / "matches.txt", "\n".join([head, *rows]) + "\n")
        doc = {"pair": self.pair.id.name, "matches": self.n, "excluded": np.flatnonzero(self.excluded).tolist(),
               "settings": self.settings,
               "F": {e.name: e.F.tolist() for e in self.result.estimators if e.F is not None and not e.error},
               "convention": "x_b^T F x_a = 0, pixels, origin at the centre of the top-left pixel"}
        fjson = write_text(folder / "F.json", json.dumps(doc, indent=1) + "\n")
        return {"features": features, "matches": matches, "text": text, "F": fjson}

    # ------------------------------------------------------------------------------------------- the page

    def command(self, cmd: dict[str, Any], export_to: Path | None = None) -> dict[str, Any]:
        """One command of the page (a JSON object: ``op`` and its arguments) -> the status (``export`` adds the
        files written). Ops: exclude / restore / toggle (``matches``), exclude_above (``px``, ``under``),
        exclude_box (``view``, ``corners``), set (``estimator``, ``threshold``, ``max_iters``), reset, export
        (into ``export_to`` only: the page names no path)."""
        op = cmd.get("op")
        args = {k: v for k, v in cmd.items() if k != "op"}
        ops = {"exclude": lambda: self.exclude(args["matches"]), "restore": lambda: self.restore(args.get("matches")),
               "toggle": lambda: self.toggle(int(args["match"])), "reset": self.reset,
               "exclude_above": lambda: self.exclude_above(float(args["px"]), args.get("under") or None),
               "exclude_box": lambda: self.exclude_box(args["view"], *np.asarray(args["corners"], float).reshape(2, 2)),
               "set": lambda: self.set(str(args["estimator"]), _opt(args.get("threshold"), float), _opt(args.get("max_iters"), int))}
        if op == "export":
            if export_to is None:
                raise FvizError("export: this viewer has no folder to export to")
            return {**self.status(), "exported": {k: str(v) for k, v in self.export(export_to).items()}}
        if op not in ops:
            raise FvizError(f"op {op!r}: one of {', '.join([*ops, 'export'])}")
        try:
            ops[op]()
        except (KeyError, TypeError, ValueError) as exc:
            raise FvizError(f"{op}: bad arguments ({exc})") from None
        return self.status()


def _opt(v, kind):
    return None if v in (None, "") else kind(v)


def _num(v) -> float | None:
    return None if v is None or not math.isfinite(float(v)) else round(float(v), 4)
