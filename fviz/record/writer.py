"""Write results to a Rerun recording, atomically: a temporary name, then a rename on success.

A crash never leaves a truncated file under the final name. ``eval`` keeps what it has on Ctrl-C by
closing the writer normally (the partial recording is valid and complete up to the last pair).

Runs end with Rerun's footer (an index of every chunk, for seeking in large files). A single pair's
recording does without it (it was 150 of 470 KB, and the viewer reads such a file whole); its last message
is ``layout.END`` instead, which tells a complete file from one cut between two messages.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
import os
import sys
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from fviz.data.pair import Pair
from fviz.diagnose import GT_SUSPECT_NOTE
from fviz.errors import FvizError
from fviz.evaluate import PairResult, agreement_text
from fviz.estimators.registry import is_baseline
from fviz.geometry import (
    AUC_THRESHOLDS_DEG, NSGD_RECALL_THRESHOLD, border_point, clip_lines, describe_epipole, epipoles, lines_in_a, lines_in_b,
    pose_auc, rotation_angle_deg, symmetric_epipolar_distance,
)
from fviz.record import layout as L

FLUSH_PAIRS = 50  # a run's recording is flushed every this many pairs (see RecordingWriter.pair_done)
JPEG_QUALITY = 50  # a KITTI frame in ~46 KB; zoomed 1.5x, no difference from 95 that a reader sees
PROBE_STEPS = 20


def batching():
    """Rerun's batcher flushing only when told (a run every FLUSH_PAIRS pairs, or the end) or past 64 MB: its
    default flushes every 200 ms, so a loaded machine cut one pair's recording into more chunks (each with
    its own schema: 240 to 252 KB for the same pair). The same data now gives the same file."""
    import rerun as rr

    cfg = rr.ChunkBatcherConfig.NEVER()
    cfg.flush_num_bytes = 64 << 20
    cfg.chunk_max_rows_if_unsorted = 8192  # Rerun's default (NEVER's 256 would split triage's unsorted pairs)
    return cfg


class RecordingWriter:
    """``with RecordingWriter(path, app_id) as w: w.rec.log(...)``; the file appears only when complete.

    Written through :mod:`fviz.atomic` (a symlink's target is replaced, special files never). Rerun's file
    sink writes into a pipe that a thread copies to the temporary file: a full disk or a size limit then
    raises here, where a sink writing the file itself stops with a log line and its flush never returns.
    Any exception (Ctrl-C included) discards the temporary file and leaves the previous version in place.
    ``index``: end the file with Rerun's footer (runs); without it (a single pair) the last message is
    ``layout.END`` (see the module docstring).
    """

    def __init__(self, path: str | Path, app_id: str = "fviz", blueprint=None, index: bool = True, recording_id: str | None = None):
        import threading

        import rerun as rr

        from fviz import atomic

        self.path = Path(path)
        self._final, self.tmp = atomic.prepare(self.path)
        try:
            self._file = open(self.tmp, "wb")
        except OSError as exc:
            raise atomic.os_error(self.path, exc) from None
        self._error: OSError | None = None
        self._pairs = 0
        read_fd, self._write_fd = os.pipe()
        self._pump = threading.Thread(target=self._copy, args=(read_fd,), name="rrd-writer", daemon=True)
        self._pump.start()
        self.rec = rr.RecordingStream(app_id, recording_id=recording_id, batcher_config=batching())
        self.rec.set_log_time_enabled(False)  # deterministic files: only the ``pair`` timeline
        self.index = index
        try:
            with _stderr_silenced(not index):  # Rerun warns that a file without its index is slower to seek
                self.rec.save(f"/dev/fd/{self._write_fd}", default_blueprint=blueprint, write_footer=index)
        except Exception as exc:
            self._finish()
            self.tmp.unlink(missing_ok=True)
            raise FvizError(f"cannot write {self.path}: {exc}") from None

    def pair_done(self) -> None:
        """Call after each pair of a run. Rerun's stream keeps what it was given until a flush (eval.rrd
        grew the process by ~60 KB per pair without one): every FLUSH_PAIRS pairs it is flushed."""
        self._pairs += 1
        if self._pairs % FLUSH_PAIRS == 0:
            self.rec.flush()

    def _copy(self, read_fd: int) -> None:
        """Pipe -> temporary file; after a write error the pipe is still drained (the sink never blocks)."""
        with open(read_fd, "rb", buffering=0) as pipe:
            while chunk := pipe.read(1 << 20):
                if self._error is None:
                    try:
                        self._file.write(chunk)
                    except OSError as exc:
                        self._error = exc

    def _finish(self) -> None:
        os.close(self._write_fd)  # the sink's own descriptor closes on disconnect: then the pump sees EOF
        self._pump.join()
        try:
            self._file.close()
        except OSError as exc:
            self._error = self._error or exc

    def close(self, commit: bool = True) -> None:
        try:
            if commit and not self.index:
                import rerun as rr

                self.rec.flush()  # what was logged goes out first: the end mark is the file's last message
                self.rec.log(L.END, rr.TextDocument("complete"), static=True)
            self.rec.flush()
            self.rec.disconnect()
        finally:
            self._finish()
        from fviz import atomic

        if commit and self._error is None:
            atomic.commit(self.path, self.tmp, self._final)
            return
        self.tmp.unlink(missing_ok=True)
        if commit:
            raise atomic.os_error(self.path, self._error)

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(commit=exc_type is None)


@contextlib.contextmanager
def _stderr_silenced(silence: bool):
    """File descriptor 2 to /dev/null for the block (a Rust library's warning, which Python cannot catch);
    nothing is done when ``silence`` is False or the process has no stderr."""
    saved = None
    if silence:
        with contextlib.suppress(OSError, ValueError):
            sys.stderr.flush()
            saved = os.dup(2)
    if saved is None:
        yield
        return
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 2)
    os.close(null)
    try:
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def encode_jpeg(image: np.ndarray) -> bytes:
    import cv2

    bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY, cv2.IMWRITE_JPEG_OPTIMIZE, 1])
    if not ok:
        raise FvizError("JPEG encoding failed")
    return buf.tobytes()


Colors = dict[str, tuple[int, int, int]]


def line_subset(result: PairResult, n: int, seed: int = 0) -> np.ndarray:
    """Indices of up to n matches for epipolar lines: evaluation matches first, a fixed random draw."""
    if result.matches is None or len(result.matches) == 0 or n <= 0:
        return np.zeros(0, int)
    pool = np.flatnonzero(result.eval_mask) if result.eval_mask.any() else np.arange(len(result.matches))
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(pool, size=min(n, len(pool)), replace=False))


def _epipole_marks(name: str, e: np.ndarray, size: tuple[int, int], unit: float = 1.0):
    """A cross at the epipole (on the border, when it is outside the image or at infinity) with its hover
    text, and the arrow towards it when outside: (strips (2, 2, 2), label, arrow (origin, vector) or None).
    ``unit``: image px per screen px (layout.screen_unit), so that the cross and arrow keep their size on screen."""
    w, h = size
    ep = describe_epipole(e, w, h)
    where = "at infinity" if ep.point is None else f"at ({ep.point[0]:.0f}, {ep.point[1]:.0f})"
    at = ep.point if ep.inside else border_point(ep.direction, w, h)
    arm = 14.0 * unit
    cross = np.array([[at - (arm, 0), at + (arm, 0)], [at - (0, arm), at + (0, arm)]])
    label = f"{name}: epipole {where}" + ("" if ep.inside else f", towards ({ep.direction[0]:+.2f}, {ep.direction[1]:+.2f})")
    arrow = None if ep.inside else (at - 56.0 * unit * ep.direction, 44.0 * unit * ep.direction)
    return cross, label, arrow


# The overview's epipoles: one glyph per F (the ground truth's a ring), so that coinciding epipoles stay
# distinguishable; unit shapes, scaled by GLYPH_PX.
GLYPH_PX = 11.0
_GLYPHS = (
    [[(-1, 0), (1, 0)], [(0, -1), (0, 1)]],  # +
    [[(-0.8, -0.8), (0.8, 0.8)], [(-0.8, 0.8), (0.8, -0.8)]],  # x
    [[(-0.8, -0.8), (0.8, -0.8), (0.8, 0.8), (-0.8, 0.8), (-0.8, -0.8)]],  # square
    [[(0, -1.1), (1.1, 0), (0, 1.1), (-1.1, 0), (0, -1.1)]],  # diamond
)  # each symmetric about the epipole: its bounding box is centred there


def _glyph(k: int, at: np.ndarray, name: str, unit: float = 1.0) -> list[np.ndarray]:
    if name == L.GT:
        return [_ring(at, 1.3 * GLYPH_PX * unit, 20)]
    return [at + GLYPH_PX * unit * np.asarray(s, float) for s in _GLYPHS[k % len(_GLYPHS)]]


TAG_ROW_PX, TAG_CHAR_PX = 24.0, 8.0  # a label's height and its width per character, screen px (with its box)


def place_tags(wants: Sequence[np.ndarray], texts: Sequence[str], size: tuple[int, int], unit: float) -> list[np.ndarray]:
    """Positions for labels wanted at ``wants`` (image px) that keep their boxes (TAG_ROW_PX high,
    TAG_CHAR_PX per character wide, in screen px) inside the image and apart: each moves up row by row, then
    down, until it overlaps none placed before it."""
    row, placed = TAG_ROW_PX * unit, []
    for want, text in zip(wants, texts):
        half = (len(text) + 2) * TAG_CHAR_PX * unit / 2
        x = min(max(want[0], half), max(size[0] - half, half))
        y0 = min(max(want[1], row), max(size[1] - row, row))
        tries = [y0 - i * row for i in range(len(wants) + 1)] + [y0 + i * row for i in range(1, len(wants) + 1)]
        free = [y for y in tries if 0 <= y <= size[1] and not any(
            abs(x - p[0]) < half + h and abs(y - p[1]) < row for p, h in placed)]
        placed.append((np.array([x, free[0] if free else y0]), half))
    return [p for p, _ in placed]


LINE_PX, CROSS_PX = 0.9, 2.0  # radii of the epipolar lines and the epipole's cross, screen px (times screen_unit)


def _log_epipoles(rec, path: str, marks: list, clear: bool, size: tuple[int, int], extra=(), unit: float = 1.0) -> None:
    """The overview's epipoles: per F a glyph of its own in its colour over a black halo, drawn above the
    lines, and its name in a label stacked above the epipole (one row per F, so that epipoles a few pixels
    apart keep both names, :func:`place_tags`) joined to it by a thin line. ``marks``: [(name, colour, where, hover
    label, arrows)]; ``extra``: more labels [(where, text)] (the residual scale's ends); ``unit``: image px per
    screen px (layout.screen_unit)."""
    import rerun as rr

    halo, strips, colors, radii, labels, arrows, points, names = [], [], [], [], [], [], [], []
    tags = place_tags([at + (0.0, -2.8 * GLYPH_PX * unit) for _, _, at, _, _ in marks], [m[0] for m in marks], size, unit)
    for k, ((name, color, at, label, arrow), tag) in enumerate(zip(marks, tags)):
        glyph = _glyph(k - 1, at, name, unit)
        halo += glyph
        strips += glyph
        colors += [color] * len(glyph)
        radii += [1.6 * unit] * len(glyph)
        labels += [label] * len(glyph)
        arrows += arrow
        strips.append(np.stack([at + (0.0, -1.3 * GLYPH_PX * unit), tag]))
        colors.append(color)
        radii.append(0.5 * unit)
        labels.append(label)
        points.append(tag)
        names.append(name)
    points += [at for at, _ in extra]
    names += [text for _, text in extra]
    rec.log(path, rr.LineStrips2D(halo + strips, colors=[(0, 0, 0)] * len(halo) + colors,
                                  radii=[3.2 * unit] * len(halo) + radii, labels=[""] * len(halo) + labels, show_labels=False,
                                  draw_order=40.0),
            rr.Points2D(points, radii=0.1, colors=[L.LABEL_ON_PHOTO] * len(marks) + [L.LABEL_OFF_PHOTO] * len(extra) or None,
                        labels=names, show_labels=True, draw_order=41.0),
            *([rr.Arrows2D(origins=[a[0] for a in arrows] or np.zeros((0, 2)), vectors=[a[1] for a in arrows] or np.zeros((0, 2)),
                           colors=[a[2] for a in arrows] or None, radii=2.0)] if arrows or clear else []))


def estimator_caption(r, result: PairResult) -> str:
    """An estimator tab's numbers, below image b: "ransac: SED 0.246 px | rotation 0.172° | ..."."""
    m = r.metrics
    return (f"{r.name}: SED {_fmt(m.get('sed_median'))} px | rotation {_fmt(m.get('rot_err_deg'))}° | translation "
            f"{_fmt(m.get('trans_err_deg'))}° | NSGD {_fmt(m.get('nsgd'))} | inliers {int(m.get('n_inliers', 0))} of "
            f"{result.n_matches} ({_fmt(100 * m.get('inlier_ratio', np.nan), 2)} %) | keypoints: its residual, dark blue "
            f"on its line to yellow >= {L.RESIDUAL_MAX_PX:g} px (scale below)")


def caption_strip(size_a: tuple[int, int], size_b: tuple[int, int], r, result: PairResult) -> tuple:
    """The estimator's numbers below the images (in image b's frame), as a labelled invisible strip:
    (strip, colour, radius, label)."""
    at = L.below_images(size_a, size_b, 18.0)
    return np.stack([at, at]), _rgb(L.LABEL_OFF_PHOTO), 0.0, estimator_caption(r, result)


def epipole_name_strip(cross: np.ndarray, label: str, size: tuple[int, int], unit: float = 1.0) -> tuple:
    """An estimator tab's epipole name as a labelled invisible strip 34 screen px above its cross (below it near
    the top edge), its box inside the image (:func:`place_tags`): (strip, colour, radius, label).
    Rerun writes a label in its strip's colour: black, on its light box, reads on any photo."""
    at = cross.mean(axis=(0, 1))
    at = place_tags([at + (0.0, -34.0 * unit if at[1] > 50.0 * unit else 22.0 * unit)], [label], size, unit)[0]
    return np.stack([at, at]), _rgb(L.LABEL_ON_PHOTO), 0.0, label


SCALE_STEP = 28.0  # one residual bin of the scale below the images, screen px


def _scale_row(size_a: tuple[int, int], size_b: tuple[int, int]) -> tuple[float, float, float, float]:
    """The residual scale's row in image b's frame: (x of its left end, y, one bin's width, image px per screen px)."""
    unit = L.screen_unit(size_a)
    x, y = L.below_images(size_a, size_b, 46.0)
    step = SCALE_STEP * unit
    return x - step * L.RESIDUAL_CLASSES / 2, y, step, unit


def scale_ends(size_a: tuple[int, int], size_b: tuple[int, int]) -> list[tuple[np.ndarray, str]]:
    """Where the residual scale's end labels go (image b's frame) and what they say."""
    x0, y, step, unit = _scale_row(size_a, size_b)
    return [(np.array([x0 - 150.0 * unit, y]), "keypoint residual: on its line (0 px)"),
            (np.array([x0 + step * L.RESIDUAL_CLASSES + 80.0 * unit, y]), f">= {L.RESIDUAL_MAX_PX:g} px off its line")]


def residual_scale(size_a: tuple[int, int], size_b: tuple[int, int]) -> list[tuple]:
    """The keypoints' colour scale below the images (under the ground truth's lines, so in every tab): one
    segment per residual bin. -> [(strip, colour, radius, label)]; the ends are labelled in the estimators'
    captions and on the overview (:func:`scale_ends`)."""
    x0, y, step, unit = _scale_row(size_a, size_b)
    colors = L.class_color(np.arange(L.RESIDUAL_CLASSES))
    return [(np.array([(x0 + c * step, y), (x0 + (c + 1) * step, y)]), colors[c], 6.0 * unit,
             f"keypoint residual {c * L.RESIDUAL_BIN_PX:g} px" + ("+" if c == L.RESIDUAL_CLASSES - 1 else ""))
            for c in range(L.RESIDUAL_CLASSES)]


def _log_marks(rec, path: str, strips: list, colors: list, radii: list, labels: list, arrows: list,
               clear: bool = True, show_labels: bool = False, static: bool = False) -> None:
    """LineStrips2D (one colour, radius and label per strip: shown with ``show_labels``, else on hover) and
    Arrows2D [(origin, vector, colour)]. clear: log the arrows even when there are none (over a timeline, so
    that earlier arrows do not linger); a single pair leaves them out, which saves their columns. static: once
    for the whole recording (no time)."""
    import rerun as rr

    marks = [rr.LineStrips2D(strips, colors=colors, radii=radii, labels=labels, show_labels=show_labels)]
    if arrows or clear:
        marks.append(rr.Arrows2D(origins=[a[0] for a in arrows] or np.zeros((0, 2)), vectors=[a[1] for a in arrows]
                                 or np.zeros((0, 2)), colors=[a[2] for a in arrows] or None, radii=2.0))
    rec.log(path, *marks, static=static)


def _fmt(v: float | None, digits: int = 3) -> str:
    return "–" if v is None or not np.isfinite(v) else f"{v:.{digits}g}"


SUMMARY_COLUMNS = (("sed_median", "SED px"), ("rot_err_deg", "rot °"), ("trans_err_deg", "trans °"),
                   ("nsgd", "NSGD"), ("inlier_ratio", "inliers"), ("agreement_nsgd", "NSGD to closest"))

_GROUND_TRUTH = {"pose": "the relative pose", "F": "a given F", "correspondences": "F fitted to the ground-truth correspondences"}


def _pair_sentence(result: PairResult) -> str:
    """What the pair is and what its metrics are computed on (KITTI frames and cameras, or a user's images)."""
    p = result.pair
    if "image_a" not in p:
        return (f"{p['kind']} pair, frame {p['frame_a']} cam {p['cam_a']} → frame {p['frame_b']} cam {p['cam_b']}; "
                f"ground truth good to ~{_fmt(p['gt_accuracy_px'], 2)} px. {result.n_matches} matches, {result.n_eval} within "
                f"{result.eval_threshold_px:g} px of the GT lines (the evaluation matches).")
    head = f"`{p['image_a']}` → `{p['image_b']}` ({p['source']}); "
    gt = p.get("ground_truth", "none")
    if gt == "none":
        return head + (f"**no ground truth**: the estimators are compared with each other. {result.n_matches} matches; "
                       "SED and inliers are over all of them, *NSGD to closest* is the NSGD of an F to the closest "
                       "other estimator's (every two: table below). No GT-based metric is computed.")
    if result.eval_points == "gt-matches":
        where = f"{result.n_eval} ground-truth correspondences (the evaluation matches)"
    else:
        where = f"{result.n_eval} within {result.eval_threshold_px:g} px of the GT lines (the evaluation matches)"
    accuracy = "" if p.get("gt_accuracy_px") is None else f", good to ~{_fmt(p['gt_accuracy_px'], 2)} px"
    return head + f"ground truth: {_GROUND_TRUTH.get(gt, gt)}{accuracy}. {result.n_matches} matches, {where}."


def precision_lines(prec: dict[str, float]) -> list[str]:
    """The match precision of a pair (fviz.geometry.precision) as one line, or none without it."""
    if not prec:
        return []
    pct = lambda k: "n/a" if not np.isfinite(prec.get(k, np.nan)) else f"{prec[k]:.0%}"  # noqa: E731
    px = [k for k in prec if k.startswith("px_prec@")]
    epi = [k for k in prec if k.startswith("epi_prec@")]
    return ["", "Match precision, before any estimator: " + ", ".join(f"{pct(k)} within {k.partition('@')[2]} px" for k in px)
            + " of F_gt; glue-factory's epi_prec@" + "/".join(k.partition("@")[2] for k in epi) + ": "
            + " / ".join(pct(k) for k in epi) + "."]


def pair_markdown(result: PairResult, probe_steps: int = 0) -> str:
    """The summary panel: the pair, a compact table (every metric is in the JSON), hints, F matrices last."""
    p = result.pair
    columns = [c for c in SUMMARY_COLUMNS if any(c[0] in r.metrics for r in result.estimators)] or list(SUMMARY_COLUMNS[:1])
    suspect = [n for n in result.notes if n.startswith(GT_SUSPECT_NOTE)]
    # reader.SUSPECT_BANNER
    lines = [f"**⚠ ground truth suspect**: {n.removeprefix(GT_SUSPECT_NOTE)}" for n in suspect] + [""] * bool(suspect)
    # the table first, so that it shows without scrolling (1600x1000); what it is computed on below it
    lines += [
        f"**{p['name']}**",
        "",
        "| F | " + " | ".join(t for _, t in columns) + " | time s |",
        "|---|" + "--:|" * (len(columns) + 1),
    ]
    for r in result.estimators:
        if r.error:
            lines.append(f"| {r.name} | failed |" + " |" * len(columns))
        else:
            lines.append(f"| {r.name} | " + " | ".join(_fmt(r.metrics.get(k)) for k, _ in columns)
                         + f" | {r.seconds:.2f} |")
    lines += ["", _pair_sentence(result), *precision_lines(result.match_precision), ""]
    if result.agreement:
        names = result.agreement["names"]
        lines += [f"**{agreement_text(result.agreement)}**", "",
                  f"NSGD between the estimators (0 = the same epipolar geometry, FM-Bench's measure; below "
                  f"{result.agreement.get('threshold', NSGD_RECALL_THRESHOLD):g} they agree):", "",
                  "| | " + " | ".join(names) + " |", "|---|" + "--:|" * len(names)]
        lines += [f"| {a} | " + " | ".join(_fmt(v) for v in row) + " |" for a, row in zip(names, result.agreement["matrix"])]
        lines.append("")
    lines += [f"- **{r.name} failed**: {r.error}" for r in result.estimators if r.error]
    lines += [f"- {n}" for n in result.notes if n not in suspect]
    lines.append("- One tab per estimator: its keypoints coloured by its residual (viridis, yellow = ≥ "
                 f"{L.RESIDUAL_MAX_PX:g} px off its line), its lines and epipole in its colour, the ground truth's white.")
    if probe_steps:
        lines.append(f"- **probe** tab: press play (or drag the `{L.PROBE_TIMELINE}` time cursor) to walk "
                     f"{probe_steps} matches, the most telling first (each step says by what; near-duplicates skipped): "
                     "each step rings one match (yellow, joined between the images) and draws its epipolar line under "
                     f"every F, thinner in estimator order; the zoomed views show each end {L.PROBE_ZOOM_PX:g} px around "
                     f"with a {L.PROBE_RING_PX:g} px ring: a line that misses it is more than {L.PROBE_RING_PX:g} px off "
                     "there (ground truth white).")
    lines.append("- SED: symmetric epipolar distance, median over the evaluation matches; rot/trans: pose error "
                 "from E = K_bᵀ F K_a; inliers: share of all matches; time s: the estimator's run time; the other "
                 "metrics: `fviz inspect pair ... --json`.")
    for r in result.estimators:
        if r.F is not None:
            F = r.F / np.linalg.norm(r.F)
            lines += ["", f"F {r.name} (unit norm)", "```", np.array2string(F, precision=5, suppress_small=False), "```"]
    return "\n".join(lines)


def _names(result: PairResult) -> list[str]:
    return [r.name for r in result.estimators]


def log_pair(rec, index: int, pair: Pair, result: PairResult, n_lines: int = 30, colors: Colors | None = None,
             probe_steps: int = 0, single_pair: bool = True, clear_reference: bool = False, motion: bool = True,
             by: str | None = None, many: bool = False) -> None:
    """Everything of one pair at ``pair`` = index (see :mod:`fviz.record.layout`): its verdict (judged on estimator
    ``by``, default every one), images, keypoints, lines, epipoles, the summary, the metrics table, and the
    comparison chart (``single_pair``) or the metric series and (``motion``) the motion tracks (runs). The reference
    lines when the notes say the ground truth is suspect; ``clear_reference`` (a run whose pairs carry that verdict:
    triage) logs them empty otherwise. ``many``: one pair of many in a stream (as a run's: every F's matches, marks cleared)."""
    import rerun as rr

    from fviz.verdicts import verdict_of

    colors = colors or L.estimator_colors(_names(result))
    rec.set_time(L.TIMELINE, sequence=index)
    verdict = result.verdict if by is None and result.verdict is not None else verdict_of(pair, result, by)
    rec.log(L.VERDICT, rr.TextDocument(verdict.markdown(), media_type="text/markdown"))
    sizes = {"a": pair.size_a, "b": pair.size_b}
    unit = L.screen_unit(pair.size_a)
    rec.log("b", rr.Transform3D(translation=[*L.offset_b(pair.size_a), 0.0]))
    for v, img in (("a", pair.image_a), ("b", pair.image_b)):
        rec.log(L.image(v), rr.EncodedImage(contents=encode_jpeg(img), media_type="image/jpeg"))
    log_pair_text(rec, result, pair_markdown(result, probe_steps))
    log_fundamentals(rec, result, pair.size_a, pair.size_b)
    m = result.matches
    sub = line_subset(result, n_lines)
    classes = match_classes(result)
    shared = single_pair and not many and L.GT in classes  # one pair: positions once, see layout.estimator_tab
    marks: dict[str, list] = {v: [] for v in L.VIEWS}  # every F's epipole: (name, colour, where, label, arrows)
    for r in result.estimators:
        if r.error:
            continue
        color = _rgb(colors[r.name])
        if not shared or r.name == L.GT:  # else the blueprint holds its classes
            rec.log(L.matches(r.name), rr.Points2D(L.match_points(m.x_a, m.x_b, pair.size_a), class_ids=classes[r.name],
                                                   radii=L.keypoint_radius(pair.size_a),
                                                   **score_labels(m)))
        lines = {"a": lines_in_a(r.F, m.x_b[sub]), "b": lines_in_b(r.F, m.x_a[sub])}
        for v, e in zip(L.VIEWS, epipoles(r.F)):
            seg, inside = clip_lines(lines[v], *sizes[v])
            cross, label, arrow = _epipole_marks(r.name, e, sizes[v], unit)
            arrows = [] if arrow is None else [(*arrow, color)]
            n = int(inside.sum())
            # lines unlabelled (hovering one names its entity, hence the estimator); the epipole's label says where
            # below image b: the estimator's numbers, or under the ground truth's lines (in every tab) the residual
            # scale; labelled strips of this entity (a Points2D would add its columns to the file)
            extra = ([] if v != "b" else residual_scale(pair.size_a, sizes[v]) if r.name == L.GT
                     else [caption_strip(pair.size_a, sizes[v], r, result)])
            shown = r.name != L.GT  # an estimator's tab names its epipole: black on a light box above the cross
            if shown:
                extra.append(epipole_name_strip(cross, label, sizes[v], unit))
            _log_marks(rec, L.est(v, r.name, "epilines"), [*seg[inside], *cross, *(x[0] for x in extra)],
                       [color] * (n + 2) + [x[1] for x in extra], [LINE_PX * unit] * n + [CROSS_PX * unit] * 2 + [x[2] for x in extra],
                       [""] * n + ["" if shown else label] * 2 + [x[3] for x in extra], arrows, clear=many or not single_pair,
                       show_labels=shown)
            marks[v].append((r.name, color, cross.mean(axis=(0, 1)), label, arrows))
    for v in L.VIEWS:
        _log_epipoles(rec, L.epipoles(v), marks[v], many or not single_pair, sizes[v],
                      scale_ends(pair.size_a, sizes[v]) if v == "b" else (), unit)
    if clear_reference or suspect_reference(result.notes) is not None:
        log_reference(rec, pair, result, colors, sub)
    if pair.gt_points is not None:
        log_labelled(rec, pair, result)
    if single_pair:
        log_comparison(rec, result, colors)
    else:
        log_series(rec, result, motion)


def log_labelled(rec, pair: Pair, result: PairResult) -> None:
    """``layout.LABELLED``: the hand-labelled correspondences (``--gt-matches``), both ends, coloured by the
    ground truth's residual on them; those at least RESIDUAL_MAX_PX off it ringed and labelled (a mislabel
    that F_gt, fitted to them all, could not follow)."""
    import rerun as rr

    gt = result.get(L.GT)
    if gt is None or gt.error:
        return
    x_a, x_b = (np.asarray(x, float) for x in pair.gt_points)
    residual = symmetric_epipolar_distance(gt.F, x_a, x_b)
    unit = L.screen_unit(pair.size_a)
    text = [f"labelled correspondence {i}: {v:.2f} px off F_gt" for i, v in enumerate(residual)]
    off = np.flatnonzero(residual >= L.RESIDUAL_MAX_PX)
    ends = L.match_points(x_a[off], x_b[off], pair.size_a)
    rings = [_ring(p, 2.5 * L.LABELLED_RADIUS_PX * unit, 24) for p in ends]
    rec.log(L.LABELLED, rr.Points2D(L.match_points(x_a, x_b, pair.size_a), class_ids=np.tile(L.residual_classes(residual), 2),
                                    radii=L.LABELLED_RADIUS_PX * unit, labels=text + text, show_labels=False, draw_order=38.0),
            rr.LineStrips2D(rings, colors=[_rgb(L.PROBE_COLOR)] * len(rings), radii=-1.0, labels=[text[i] for i in off] * 2,
                            show_labels=True, draw_order=39.0))


def score_labels(m) -> dict:
    """Hover text of a user's matches that carry their matcher's scores (``--matches``): both ends alike."""
    if getattr(m, "scores", None) is None:
        return {}
    text = [f"match {i}: score {v:.3g}" for i, v in enumerate(m.scores)]
    return {"labels": text + text, "show_labels": False}


def match_classes(result: PairResult) -> dict[str, np.ndarray]:
    """{estimator: class ids of ``layout.matches`` (residual bin and inlier flag, see layout.residual_classes),
    both ends of each match alike}, failed ones left out. -> (2N,) each."""
    return {r.name: np.tile(L.residual_classes(r.residuals_px, r.inliers), 2) for r in result.estimators if not r.error}


def _rgb(color) -> np.ndarray:
    return np.asarray(color, np.uint8)


def bar_lengths(values: Sequence[float], width: float) -> np.ndarray:
    """Bar lengths on a log scale, so that 0.17 and 0.21 px part beside 7.1: the largest value fills
    ``width``, a decade below the smallest positive one (or 1 % of the largest) starts at 0; zero, negative and
    missing values get no bar. (N,) -> (N,)."""
    v = np.asarray(values, float)
    pos = v[np.isfinite(v) & (v > 0)]
    if not len(pos):
        return np.zeros(len(v))
    hi = float(pos.max())
    lo = min(float(pos.min()) / 10, hi / 100)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = width * (np.log10(v) - np.log10(lo)) / (np.log10(hi) - np.log10(lo))
    return np.where(np.isfinite(v) & (v > 0), out, 0.0)


# Per-point residual CDF on the overview's chart: share of the evaluation matches within x px of each F's lines.
RESIDUAL_CDF_PX = np.geomspace(0.01, 10.0, 41)


def log_comparison(rec, result: PairResult, colors: Colors) -> None:
    """The overview's chart, drawn in 2D (y down): per metric a title and one horizontal bar per F in its
    colour on a log scale (:func:`bar_lengths`), each labelled "name value" just right of its bar; below, the
    CDF of each F's residuals (SED) over the evaluation matches (log x)."""
    import rerun as rr

    width, pitch, head = L.BAR_WIDTH, L.BAR_PITCH, L.BAR_HEAD
    bars, bar_colors, bar_radii, points, labels = [], [], [], [], []
    y = 0.0
    for key, title in L.COMPARED_METRICS:
        values = [np.nan if r.error else float(r.metrics.get(key, np.nan)) for r in result.estimators]
        if not any(np.isfinite(values)):
            continue
        if key == "agreement_nsgd" and result.agreement:
            y = _agreement_matrix(result.agreement, title, y, bars, bar_colors, bar_radii, points, labels)
            continue
        points.append((width / 2, y - L.LABEL_DROP))
        labels.append(title + " (log scale)")
        y += head
        for r, v, length in zip(result.estimators, values, bar_lengths(values, width)):
            if r.name == L.GT and v == 0:
                continue  # the ground truth's own pose error and NSGD: zero by definition
            bars.append([(0.0, y), (max(length, 0.5), y)])
            bar_colors.append(_rgb(colors[r.name]))
            bar_radii.append(pitch / 3)
            text = f"{r.name}: {'error' if r.error else _fmt(v)}"
            points.append((max(length, 0.5) + 12.0 + 4.2 * len(text), y - L.LABEL_DROP))  # centred on its point
            labels.append(text)
            y += pitch
        y += pitch / 2
    y0 = y + head  # the residual CDF panel
    ok = [r for r in result.estimators if not r.error and r.residuals_px is not None and result.eval_mask is not None]
    u = np.log10(RESIDUAL_CDF_PX)
    px = width * (u - u[0]) / (u[-1] - u[0])
    for r in ok:
        recall = cumulative_curve(r.residuals_px[result.eval_mask], RESIDUAL_CDF_PX)
        bars.append(np.stack([px, y0 + L.CDF_H * (1 - recall)], -1))
        bar_colors.append(_rgb(colors[r.name]))
        bar_radii.append(1.5)
    if ok:
        bars.append([(0.0, y0), (0.0, y0 + L.CDF_H), (width, y0 + L.CDF_H)])
        bar_colors.append(_rgb((200, 200, 200)))
        bar_radii.append(0.6)
        points += [(x, y - L.LABEL_DROP) for x, y in ((width / 2, y0 - 16.0), (0.0, y0 + L.CDF_H + 14.0),
                   (width * 2 / 3, y0 + L.CDF_H + 14.0), (width, y0 + L.CDF_H + 14.0), (-30.0, y0), (-30.0, y0 + L.CDF_H))]
        labels += ["matches with SED < x (per F)", "0.01", "1 px", "10", "100%", "0"]
    # labels white: Rerun draws them on grey boxes, where coloured text is hard to read; the bar beside each
    # label carries the colour
    rec.log(L.COMPARE, rr.LineStrips2D(bars, colors=bar_colors, radii=bar_radii),
            rr.Points2D(points, radii=0.1, colors=[(255, 255, 255)], labels=labels, show_labels=True))


def _agreement_matrix(ag: dict, title: str, y: float, bars: list, bar_colors: list, bar_radii: list, points: list,
                      labels: list) -> float:
    """The comparison chart's agreement matrix (no ground truth), appended to its strips and labels from ``y``
    down: a cell per two estimators with their NSGD, green where they agree (< the threshold), red where not.
    -> the y below it."""
    names, m = ag["names"], np.asarray(ag["matrix"], float)
    pitch, x0 = L.BAR_PITCH, L.MATRIX_NAMES_W
    cell = min(100.0, (L.BAR_LABEL_X + 80.0 - x0) / len(names))
    points.append(((L.BAR_LABEL_X + 90.0 - 2 * pitch) / 2, y - L.LABEL_DROP))  # the middle of the chart's view
    labels.append(title)
    y += L.BAR_HEAD
    for j, name in enumerate(names):  # the column names
        points.append((x0 + (j + 0.5) * cell, y - L.LABEL_DROP))
        labels.append(name)
    for i, name in enumerate(names):
        y += pitch
        points.append((x0 / 2, y - L.LABEL_DROP))
        labels.append(name)
        for j in range(len(names)):
            bars.append([(x0 + j * cell + 6.0, y), (x0 + (j + 1) * cell - 6.0, y)])
            agree = m[i, j] < ag.get("threshold", NSGD_RECALL_THRESHOLD)
            bar_colors.append(_rgb(L.SAME_COLOR if i == j else L.AGREE_COLOR if agree else L.DIFFER_COLOR))
            bar_radii.append(0.45 * pitch)
            if i != j:
                points.append((x0 + (j + 0.5) * cell, y - L.LABEL_DROP))
                labels.append(_fmt(m[i, j], 2))
    return y + 1.5 * pitch


def log_pair_text(rec, result: PairResult, text: str | None = None) -> None:
    """pair/info, the summary, the metrics table and the estimators' errors of the pair at the current time."""
    import rerun as rr

    rec.log(L.PAIR_INFO, rr.TextDocument(result.pair.get("name", "")))
    rec.log(L.SUMMARY, rr.TextDocument(text or pair_markdown(result), media_type="text/markdown"))
    log_metrics_table(rec, result)
    for r in result.estimators:
        if r.error:
            rec.log(L.error(r.name), rr.TextLog(f"{r.name} failed: {r.error}", level="ERROR"))


def log_metrics_table(rec, result: PairResult) -> None:
    """``pair/metrics``: the estimators' names and one column per metric, NaN where an estimator failed."""
    import rerun as rr

    keys = sorted({k for r in result.estimators for k in r.metrics})
    columns = {k: np.array([r.metrics.get(k, np.nan) if not r.error else np.nan for r in result.estimators], float)
               for k in keys}
    rec.log(L.PAIR_METRICS, rr.AnyValues(estimators=_names(result), **columns))


def log_fundamentals(rec, result: PairResult, size_a: tuple[int, int], size_b: tuple[int, int]) -> None:
    """``pair/fundamental``: the F's of the pair (failed estimators left out) and the image sizes, which a
    click needs (:mod:`fviz.interactive`)."""
    import rerun as rr

    ok = [r for r in result.estimators if not r.error and r.F is not None]
    rec.log(L.PAIR_FS, rr.AnyValues(estimators=[r.name for r in ok], F=np.array([r.F for r in ok], float).reshape(-1),
                                    size_a=np.array(size_a, float), size_b=np.array(size_b, float)))


def motion_values(result: PairResult) -> dict[str, list[float]]:
    """{track: one value per F} (``motion/*`` in :mod:`fviz.record.layout`): the image-a epipole, and where
    the estimator's pose is known (``R``, ``t`` of its result) the rotation angle and the translation
    direction with the ground truth's sign. NaN where unknown."""
    w, h = result.pair.get("size_a", (0, 0))  # a pair that failed as a whole has no size, and no F
    gt = result.get(L.GT)
    t_gt = None if gt is None or getattr(gt, "t", None) is None else np.asarray(gt.t, float)
    out: dict[str, list[float]] = {k: [] for k, _ in L.MOTION_TRACKS}
    for r in result.estimators:
        v = dict.fromkeys(out, np.nan)
        if r.F is not None:
            ep = describe_epipole(epipoles(r.F)[0], w, h)
            if ep.point is None or np.abs(ep.point - (w / 2, h / 2)).max() > 50 * max(w, h):
                v["epipole_dir_deg"] = float(np.degrees(np.arctan2(ep.direction[1], ep.direction[0])))
            else:
                v["epipole_x"], v["epipole_y"] = map(float, ep.point)
        R, t = getattr(r, "R", None), getattr(r, "t", None)
        if R is not None:
            v["rotation_deg"] = float(rotation_angle_deg(R))
        if t is not None and np.linalg.norm(t) > 0:
            t = np.asarray(t, float) / np.linalg.norm(t)
            if t_gt is not None and t @ t_gt < 0:
                t = -t
            v["t_x"], v["t_y"], v["t_z"] = map(float, t)
        for k in out:
            out[k].append(v[k])
    return out


def log_series(rec, result: PairResult, motion: bool = True) -> None:
    """The metric series (and with ``motion`` the motion tracks) of the pair at the current time (runs of many
    pairs): one value per F, in the order of the series names (NaN for a failed estimator); an error metric's
    log10 beside it, for its plot (layout.metric_plot)."""
    import rerun as rr

    for key in L.SERIES_METRICS:
        values = [r.metrics.get(key, np.nan) if not r.error else np.nan for r in result.estimators]
        rec.log(L.metric(key), rr.Scalars(values))
        if key in L.LOG_METRICS:
            rec.log(L.metric_plot(key), rr.Scalars(L.log_values(values)))
    for key, values in (motion_values(result).items() if motion else ()):
        rec.log(L.motion(key), rr.Scalars(values))


PROBE_BY_SCORE = "score"
PROBE_SPACING_PX = 20.0  # screen px: a match this near one already walked (at either end) is a near-duplicate


@dataclass
class ProbePoints:
    """What the probe walks: points of both images (matches, or the hand-labelled correspondences of
    ``--gt-matches``), every F's residual (SED, px) on each, the indices to walk in order and why that order."""

    x_a: np.ndarray
    x_b: np.ndarray
    residuals: dict[str, np.ndarray]
    order: np.ndarray
    what: str  # "match" or "labelled correspondence"
    rank: str  # the order, in words


def _drivers(result: PairResult) -> list:
    """The estimators whose disagreement orders the probe: those fitted to the matches (never a baseline; the
    networks only when nothing else is there)."""
    from fviz.diagnose import fits_matches

    ok = [r for r in result.estimators if not r.error and r.name != L.GT and not is_baseline(r.name)]
    return [r for r in ok if fits_matches(r.name)] or ok


def probe_points(result: PairResult, by: str | None = None, gt_points=None) -> ProbePoints:
    """The probe's points and order, most telling first. ``by``: an estimator's residual, or ``score`` (the
    user's matcher's scores, least confident first). By default what the pair's question needs:
    hand-labelled correspondences (``gt_points``: (x_a, x_b)) by the ground truth's residual (a mislabelled one
    first); no evaluation match: every match by the ground truth's residual (the matcher's errors); otherwise
    the evaluation matches (every match without ground truth) by the disagreement of the estimators fitted to
    the matches and the ground truth: the largest residual minus the smallest."""
    m, ok = result.matches, [r for r in result.estimators if not r.error]
    gt = result.get(L.GT)
    gt = None if gt is None or gt.error else gt
    if gt_points is not None and gt is not None and by != PROBE_BY_SCORE:
        x_a, x_b = (np.asarray(x, float) for x in gt_points)
        residuals = {r.name: symmetric_epipolar_distance(r.F, x_a, x_b) for r in ok}
        idx, what = np.arange(len(x_a)), "labelled correspondence"
    else:
        x_a, x_b = (np.zeros((0, 2)), np.zeros((0, 2))) if m is None else (m.x_a, m.x_b)
        residuals = {r.name: r.residuals_px for r in ok}
        idx = np.flatnonzero(result.eval_mask) if result.eval_mask is not None else np.zeros(0, int)
        what = "match"
    if by == PROBE_BY_SCORE:
        scores = getattr(m, "scores", None)
        if scores is None:
            raise FvizError(f"--probe-by {by}: these matches have no scores (give --matches with the matcher's scores)")
        return ProbePoints(x_a, x_b, residuals, idx[np.argsort(scores[idx], kind="stable")], what,
                           "the matcher's score, lowest first")
    if by is not None and result.get(by) is None:
        raise FvizError(f"--probe-by {by}: not an estimator of this pair ({', '.join(_names(result))})")
    if by is not None:
        score, rank = residuals.get(by), f"{by}'s residual"
    elif gt is not None and (what != "match" or not len(idx)):
        idx = np.arange(len(x_a))
        score = residuals[L.GT]
        rank = ("the ground truth's residual: a mislabelled correspondence first" if what != "match" else
                "the ground truth's residual over all matches (no evaluation match: the matcher's errors)")
    else:
        drivers = [r.name for r in _drivers(result)] + ([L.GT] if gt is not None else [])
        score = (np.max([residuals[n] for n in drivers], 0) - np.min([residuals[n] for n in drivers], 0)
                 if len(drivers) > 1 else residuals[drivers[0]] if drivers else None)
        rank = f"disagreement of {', '.join(drivers)} (largest residual minus smallest)"
    if score is None or not len(idx):
        return ProbePoints(x_a, x_b, residuals, idx, what, rank)
    return ProbePoints(x_a, x_b, residuals, idx[np.argsort(-np.nan_to_num(score[idx], nan=-1.0), kind="stable")], what, rank)


def spread_out(points: ProbePoints, spacing: float, steps: int) -> np.ndarray:
    """The first ``steps`` of the order, skipping near-duplicates: a point within ``spacing`` image px of one
    already taken, at either end (the same keypoint matched twice, a cluster of one structure)."""
    taken: list[int] = []
    for j in points.order:
        if len(taken) >= steps:
            break
        if not taken or min(np.linalg.norm(points.x_a[taken] - points.x_a[j], axis=1).min(),
                            np.linalg.norm(points.x_b[taken] - points.x_b[j], axis=1).min()) >= spacing:
            taken.append(int(j))
    return np.array(taken, int)


def probe_walk(pair: Pair, result: PairResult, by: str | None = None, steps: int = PROBE_STEPS) -> tuple[ProbePoints, np.ndarray]:
    """The probe's points (:func:`probe_points`) and the indices it walks: at most ``steps``, near-duplicates
    (within PROBE_SPACING_PX on screen) skipped."""
    points = probe_points(result, by, pair.gt_points)
    return points, spread_out(points, PROBE_SPACING_PX * L.screen_unit(pair.size_a), max(steps, 0))


def _ring(center: np.ndarray, radius: float = 12.0, n: int = 16) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n + 1)
    return center + radius * np.stack([np.cos(t), np.sin(t)], -1)


def empty_probe_text(result: PairResult, steps: int, fs: list) -> str:
    """Why the probe has no step: it is off, no F gives a line, or there is no match to walk."""
    if steps <= 0:
        return "**No probe**: it is off (`--probe 0`)."
    if not fs:
        return "**No probe**: no estimator gave an F (and there is no ground truth): no epipolar line to draw."
    return f"**No probe**: {result.n_matches} matches, none to walk."


def log_probe(rec, index: int, pair: Pair, result: PairResult, steps: int = PROBE_STEPS, by: str | None = None,
              colors: Colors | None = None) -> int:
    """The ``probe`` timeline: step k rings the k-th point of :func:`probe_points` (near-duplicates skipped) in
    both images, joins them, and draws its epipolar line under every F (in a: F^T x_b, in b: F x_a) in the F's
    colour; the zoomed views follow it (``probe/zoom/{v}``); the residuals as text. -> the steps logged."""
    import rerun as rr

    colors = colors or L.estimator_colors(_names(result))
    ok = [r for r in result.estimators if not r.error]
    points, order = probe_walk(pair, result, by, steps) if ok and steps > 0 else (None, [])
    if not len(order):  # the probe tab says why it is empty
        rec.set_time(L.PROBE_TIMELINE, sequence=0)
        rec.set_time(L.TIMELINE, sequence=index)
        rec.log(L.PROBE_TEXT, rr.TextDocument(empty_probe_text(result, steps, ok), media_type="text/markdown"))
        return 0
    unit = L.screen_unit(pair.size_a)
    sizes = {"a": pair.size_a, "b": pair.size_b}
    shift = L.offset_b(pair.size_a)
    marker = L.PROBE_COLOR
    for k, j in enumerate(order):
        rec.set_time(L.PROBE_TIMELINE, sequence=k)
        rec.set_time(L.TIMELINE, sequence=index)
        xa, xb = points.x_a[j], points.x_b[j]
        for v, lines, at in (("a", [lines_in_a(r.F, xb[None]) for r in ok], xa), ("b", [lines_in_b(r.F, xa[None]) for r in ok], xb)):
            seg, inside = clip_lines(np.concatenate(lines), *sizes[v])
            drawn = [r for r, i in zip(ok, inside) if i]
            rings = [_ring(at, L.PROBE_RING_PX, 12), _ring(at, L.PROBE_MARK_PX * unit, 12)]
            strips = [*seg[inside], *rings] + ([[xa, xb + shift]] if v == "a" else [])  # a's frame is the root
            # radii in UI points (negative): the same on screen in the whole images and in the zoomed views
            widths = list(-np.linspace(1.6, 0.7, len(drawn))) + [-0.8, -1.2, -0.8][: len(strips) - len(drawn)]
            _log_marks(rec, L.probe(v), strips, [_rgb(colors[r.name]) for r in drawn] + [marker] * (len(strips) - len(drawn)),
                       widths, [f"{r.name}: epipolar line of {points.what} {j}" for r in drawn]
                       + [f"{points.what} {j}"] * (len(strips) - len(drawn)), [], clear=False)
            rec.log(L.probe_zoom(v), rr.Transform3D.from_fields(translation=[*(at + (shift if v == "b" else 0.0)), 0.0]))
        rows = [f"| {r.name} | {points.residuals[r.name][j]:.2f} |" for r in ok]
        scores = getattr(result.matches, "scores", None) if points.what == "match" else None
        text = "\n".join([
            f"**step {k + 1} of {len(order)}**: {points.what} {j}, a ({xa[0]:.1f}, {xa[1]:.1f}) → b ({xb[0]:.1f}, {xb[1]:.1f})"
            + ("" if scores is None else f", score {scores[j]:.3g}"),
            "", "| F | SED px |", "|---|--:|", *rows, "",
            f"By {points.rank}; near-duplicates skipped. Zoomed: a line outside the {L.PROBE_RING_PX:g} px ring misses "
            "by more (summary: how to read the probe).",
        ])
        rec.log(L.PROBE_TEXT, rr.TextDocument(text, media_type="text/markdown"))
    return len(order)


def log_static(rec, estimator_names: list[str], series: bool = False, legend: bool = True, points: bool = False,
               ranges: dict | None = None, motion: bool = True) -> None:
    """Once per recording: the residual legend (``legend``: when it holds matches) and, for runs (``series``),
    the names, colours and marks of the metric series and (``motion``) the motion tracks (:func:`series_styles`),
    and their legend (``layout.LEGEND``)."""
    if legend:
        rec.log("/", L.annotation_context(), static=True)
    if series:
        colors = L.estimator_colors(estimator_names)
        for path in SERIES_PATHS if motion else [p for p in SERIES_PATHS if not p.startswith("motion/")]:
            cut = (ranges or {}).get(path) or (0, 0, {})
            rec.log(path, *series_styles(colors, points or path in POINT_PATHS, cut[2]), static=True)
        log_legend(rec, colors)


# The series' values (what readers read) and, for the errors, the log10 their plots draw (layout.metric_plot).
VALUE_PATHS = tuple([L.metric(k) for k in L.SERIES_METRICS] + [L.motion(k) for k, _ in L.MOTION_TRACKS])
SERIES_PATHS = VALUE_PATHS + tuple(L.metric_plot(k) for k in L.SERIES_METRICS if k in L.LOG_METRICS)
POINT_PATHS = frozenset({L.motion("epipole_dir_deg")})  # sporadic samples (the pairs whose epipole is at infinity)
MARKER_SIZE = 3.0


def series_styles(colors: Colors, points: bool = False, cut: Iterable[str] = ()) -> list:
    """How a plot draws its series (one per F, named and in its colour): lines joining consecutive pairs, or
    points (``points``: series over triage's ranks, where neighbours are unrelated pairs; a series ``cut`` off
    the plot's range: its off-scale swings would streak across the plot). -> archetypes to log on the series."""
    import rerun as rr

    names, rgb = list(colors), [_rgb(c) for c in colors.values()]
    dots = [points or n in set(cut) for n in names]
    out = [] if all(dots) else [rr.SeriesLines(names=names, colors=rgb, visible_series=[not d for d in dots])]
    if any(dots):
        out.append(rr.SeriesPoints(names=names, colors=rgb, visible_series=dots, marker_sizes=[MARKER_SIZE] * len(names)))
    return out


def log_legend(rec, colors: Colors, path: str = L.LEGEND, origin=(0.0, 0.0), pitch: float = 24.0,
               labels: dict[str, str] | None = None) -> None:
    """One row per F: a bar in its colour and its name beside it (or ``labels[name]``, centred as far right as
    it is long, ~7 units a character), labels white on Rerun's grey boxes, their points 0.4 rows up (Rerun
    draws a label below its point), drawn in 2D on the charts' dark background. -> rows of ``pitch`` units
    from ``origin``."""
    import rerun as rr

    x0, y0 = origin
    rows = list(colors.items())
    bars = [[(x0, y0 + i * pitch), (x0 + 40.0, y0 + i * pitch)] for i in range(len(rows))]
    text = [(labels or {}).get(n, "ground truth" if n == L.GT else n) for n, _ in rows]
    xs = [x0 + 120.0 if labels is None else x0 + 60.0 + 3.6 * len(t) for t in text]
    rec.log(path, rr.LineStrips2D(bars, colors=[_rgb(c) for _, c in rows], radii=pitch / 4),
            rr.Points2D([(x, y0 + (i - 0.4) * pitch) for i, x in enumerate(xs)], radii=0.1, colors=[(255, 255, 255)],
                        labels=text, show_labels=True), static=True)


# ---------------------------------------------------------------------------------------------- runs: ranges, curves


def series_values(results: Iterable[PairResult]) -> dict[str, dict[str, list[float]]]:
    """{series path: {F: its value on each pair (NaN where unknown)}} of the runs' plots (metrics and motion),
    as :func:`log_series` logs them; also ``metrics/{key}`` of the cumulative curves' metrics (CURVE_METRICS)."""
    out: dict[str, dict[str, list[float]]] = {}
    keys = dict.fromkeys([*L.SERIES_METRICS, *(k for k, *_ in CURVE_METRICS)])
    for result in results:
        names = _names(result)
        per = {L.metric(k): [np.nan if r.error else r.metrics.get(k, np.nan) for r in result.estimators] for k in keys}
        per.update({L.motion(k): v for k, v in motion_values(result).items()})
        for path, values in per.items():
            for n, v in zip(names, values):
                out.setdefault(path, {}).setdefault(n, []).append(float(v))
    return out


def ranges_of_values(values: dict[str, dict[str, Sequence[float]]]) -> dict[str, tuple | None]:
    """{plotted path: its plot's y range (layout.series_range) or None} of :func:`series_values` (or the values
    the recording holds): an error metric's on its log10 (every value above LOG_FLOOR), the other metrics'
    from 0 with every value, the motion tracks' leaving a wild series out."""
    out = {}
    for path, per in values.items():
        key = path.removeprefix("metrics/")
        if path.startswith("motion/"):
            out[path] = L.series_range(per, L.TRACK_FLOOR.get(path.removeprefix("motion/"), 1e-3))
        elif key in L.LOG_METRICS:
            logs = {n: L.log_values(np.where(np.asarray(v, float) > L.LOG_FLOOR, v, np.nan)) for n, v in per.items()}
            out[L.metric_plot(key)] = L.series_range(logs, 0.1, cut=False)
        elif key in L.SERIES_METRICS:
            out[path] = L.series_range(per, zero=True, cut=False)
    return out


def series_ranges_of(results: Iterable[PairResult]) -> dict[str, tuple | None]:
    return ranges_of_values(series_values(results))


# The cumulative error curves of a run: (metric, title, thresholds, log x axis).
CURVE_METRICS = (
    ("pose_err_deg", "pose error (deg)", np.geomspace(0.01, 30.0, 71), True),
    ("sed_median", "median SED (px)", np.geomspace(0.01, 10.0, 61), True),
    ("nsgd", "NSGD (FM-Bench)", np.geomspace(1e-3, 1.0, 61), True),
)
# The standard figures' thresholds, marked on their curves: (x, label)
CURVE_MARKS = {"pose_err_deg": [(t, f"{t:g}°") for t in AUC_THRESHOLDS_DEG],
               "nsgd": [(NSGD_RECALL_THRESHOLD, f"{NSGD_RECALL_THRESHOLD:g}")]}


def cumulative_curve(values: Sequence[float], thresholds: np.ndarray) -> np.ndarray:
    """Share of the pairs whose value is below each threshold; NaN (a failure) never is. (P,), (T,) -> (T,)."""
    v = np.nan_to_num(np.asarray(values, float), nan=np.inf)
    return (v[:, None] < np.asarray(thresholds, float)[None]).mean(axis=0) if len(v) else np.zeros(len(thresholds))


def curve_figures(per_pair: dict[str, dict[str, Sequence[float]]], name: str) -> str:
    """The standard figures read off ``name``'s curves (those it has): "AUC@5/10/20° 0.74/0.87/0.94, NSGD recall 100%"."""
    out = []
    if (pose := per_pair.get("pose_err_deg", {}).get(name)) is not None:
        slash = "/".join(f"{t:g}" for t in AUC_THRESHOLDS_DEG)
        out.append(f"AUC@{slash}° " + "/".join(f"{a:.2f}" for a in pose_auc(pose)))
    if (nsgd := per_pair.get("nsgd", {}).get(name)) is not None:
        out.append(f"NSGD recall {cumulative_curve(nsgd, [NSGD_RECALL_THRESHOLD])[0]:.0%}")
    return ", ".join(out)


def log_curves(rec, per_pair: dict[str, dict[str, Sequence[float]]], colors: Colors) -> None:
    """``curves/{metric}``: per metric of CURVE_METRICS a panel with one curve per F in its colour (share of the
    pairs below x), axes and ticks, the standard figures' thresholds marked (CURVE_MARKS), and the curves'
    values (AnyValues: ``thresholds``, ``estimators``, ``recall`` row-major F x threshold) for readers; below, the
    legend with each F's figures (AUC, NSGD recall). ``per_pair``: {metric: {F: value per pair, NaN failed}}."""
    import rerun as rr

    white, grey = (200, 200, 200), (150, 150, 150)
    for i, (key, title, thresholds, log_x) in enumerate(CURVE_METRICS):
        per = {n: v for n, v in per_pair.get(key, {}).items() if n != L.GT}
        if not per:
            continue
        x0 = i * (L.CURVE_W + L.CURVE_GAP)
        u = np.log10(thresholds) if log_x else thresholds

        def screen_x(t: float) -> float:
            return x0 + L.CURVE_W * ((np.log10(t) if log_x else t) - u[0]) / (u[-1] - u[0])

        recall = {n: cumulative_curve(v, thresholds) for n, v in per.items()}
        strips = [np.stack([screen_x(thresholds), L.CURVE_H * (1 - r)], -1) for r in recall.values()]
        lo, hi = float(thresholds[0]), float(thresholds[-1])
        ticks_x = ([10.0**k for k in range(math.ceil(math.log10(lo) - 1e-9), math.floor(math.log10(hi) + 1e-9) + 1)]
                   if log_x else list(np.linspace(lo, hi, 5)))
        axes = [[(x0, 0.0), (x0, L.CURVE_H), (x0 + L.CURVE_W, L.CURVE_H)]]
        tick_pos, tick_labels = [], []
        for t in ticks_x:
            axes.append([(screen_x(t), L.CURVE_H), (screen_x(t), L.CURVE_H + 6)])
            tick_pos.append((screen_x(t), L.CURVE_H + 22))
            tick_labels.append(f"{t:g}")
        for y in (0.0, 0.5, 1.0):
            axes.append([(x0 - 6, L.CURVE_H * (1 - y)), (x0, L.CURVE_H * (1 - y))])
            tick_pos.append((x0 - 30, L.CURVE_H * (1 - y)))
            tick_labels.append(f"{y:.0%}")
        marks = [[(screen_x(t), 0.0), (screen_x(t), L.CURVE_H)] for t, _ in CURVE_MARKS.get(key, ())]
        for t, label in CURVE_MARKS.get(key, ()):  # above the panel, below its title
            tick_pos.append((screen_x(t), -24.0))
            tick_labels.append(label)
        tick_pos.append((x0 + L.CURVE_W / 2, -52.0))
        tick_labels.append(f"share of the pairs with {title} < x" + (" (log x)" if log_x else ""))
        rec.log(f"{L.CURVES}/{key}",
                rr.LineStrips2D(strips + axes + marks, colors=[_rgb(colors[n]) for n in recall] + [white] * len(axes) + [grey] * len(marks),
                                radii=[2.0] * len(strips) + [0.8] * len(axes) + [0.6] * len(marks)),
                rr.Points2D(tick_pos, radii=0.1, colors=[(255, 255, 255)], labels=tick_labels, show_labels=True),
                rr.AnyValues(thresholds=np.asarray(thresholds, float), estimators=list(recall),
                             recall=np.concatenate(list(recall.values()))), static=True)
    shown = {n: c for n, c in colors.items() if n != L.GT}
    figures = {n: curve_figures(per_pair, n) for n in shown}
    log_legend(rec, shown, f"{L.CURVES}/legend", (0.0, L.CURVE_H + 70.0),
               labels={n: f"{n}: {f}" if f else n for n, f in figures.items()})


def suspect_reference(notes: Sequence[str]) -> str | None:
    """The F to trust instead of the ground truth when the notes say it is suspect (None otherwise)."""
    return next((n.rpartition("(reference: ")[2].rstrip(")") for n in notes if n.startswith(GT_SUSPECT_NOTE)), None)


def suspect_notice(notes: Sequence[str]) -> str:
    """The overview's warning when the notes say the ground truth is suspect ("" otherwise)."""
    ref = suspect_reference(notes)
    return "" if ref is None else f"GROUND TRUTH SUSPECT: thick labelled lines = REFERENCE, {ref}'s F (summary) - "


def reference_label(name: str) -> str:
    return f"thick lines: REFERENCE = {name}'s F (the ground truth is suspect)"


def log_reference(rec, pair: Pair, result: PairResult, colors: Colors, sub: np.ndarray) -> bool:
    """``layout.REFERENCE``: when the notes name a reference F (ground truth suspect), its epipolar lines of the
    first REFERENCE_LINES line matches ``sub`` in both images, where both cross their image (image b's shifted
    below a), thick, in its colour, one label per image; otherwise empty (a run's pair: no lines linger from a
    previous one). -> whether lines were drawn."""
    import rerun as rr

    name = suspect_reference(result.notes)
    r = None if name is None else result.get(name)
    strips = []
    if r is not None and not r.error and r.F is not None:
        k = sub[: L.REFERENCE_LINES]
        seg_a, in_a = clip_lines(lines_in_a(r.F, result.matches.x_b[k]), *pair.size_a)
        seg_b, in_b = clip_lines(lines_in_b(r.F, result.matches.x_a[k]), *pair.size_b)
        both = in_a & in_b
        strips = [*seg_a[both], *(seg_b[both] + L.offset_b(pair.size_a))]
    n = len(strips)
    if n:  # the names: black on Rerun's light label box (text takes its strip's colour), top right of each image
        strips += [np.stack([at, at]) for at in (np.array([0.8 * pair.size_a[0], 22.0]),
                                                  np.array([0.8 * pair.size_b[0], 22.0]) + L.offset_b(pair.size_a))]
    colors_ = [_rgb(colors[name])] * n + [_rgb(L.LABEL_ON_PHOTO)] * (len(strips) - n) if n else []
    rec.log(L.REFERENCE, rr.LineStrips2D(strips, colors=colors_ or None, radii=[L.REFERENCE_RADIUS] * n + [0.0] * (len(strips) - n),
                                         labels=[""] * n + [reference_label(name)] * (len(strips) - n) or None,
                                         show_labels=True, draw_order=35.0))
    return n > 0


def pair_blueprint(pair: Pair, result: PairResult):
    """The stored layout of one pair's recording (:func:`fviz.record.layout.blueprint`, single pair)."""
    names = _names(result)
    classes = match_classes(result)
    return L.blueprint(names, (pair.size_a, pair.size_b), single_pair=True, classes=classes if L.GT in classes else None,
                       notice=suspect_notice(result.notes), verdict=True)


def log_pair_recording(rec, pair: Pair, result: PairResult, n_lines: int = 30, probe_steps: int = PROBE_STEPS,
                       probe_by: str | None = None, index: int = 0, many: bool = False, legend: bool = True) -> int:
    """Everything ``inspect pair`` records of one pair into ``rec`` at ``pair`` = index: ``legend``, images, lines,
    epipoles, summary, comparison, and the ``probe`` timeline (``many``: see :func:`log_pair`). -> the probe steps."""
    colors = L.estimator_colors(_names(result))
    steps = len(probe_walk(pair, result, probe_by, probe_steps)[1])  # checks probe_by before logging
    log_static(rec, _names(result), legend=legend)
    rec.set_time(L.PROBE_TIMELINE, sequence=0)
    log_pair(rec, index, pair, result, n_lines, colors, steps, many=many)
    log_probe(rec, index, pair, result, probe_steps, probe_by, colors)
    return steps


def write_pair_recording(path: str | Path, pair: Pair, result: PairResult, n_lines: int = 30,
                         probe_steps: int = PROBE_STEPS, probe_by: str | None = None) -> Path:
    """One pair, one file, with its blueprint stored (what ``fviz inspect pair`` writes)."""
    probe_points(result, probe_by)  # a bad --probe-by fails before any file is opened
    with RecordingWriter(path, "fviz-inspect", pair_blueprint(pair, result), index=False) as w:
        log_pair_recording(w.rec, pair, result, n_lines, probe_steps, probe_by)
    return Path(path)
