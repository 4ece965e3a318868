"""What one pair's recording draws with: colours, rings, each F's epipole (a cross, or an arrow towards it) and the
overview's glyphs, label placement (:func:`place_tags`), the residual scale below the images, and an entity's
strips and arrows (:func:`log_marks`)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fviz.evaluate import PairResult
from fviz.geometry import border_point, describe_epipole
from fviz.record import layout as L
from fviz.record.placement import below_images, screen_unit


Colors = dict[str, tuple[int, int, int]]


def names_of(result: PairResult) -> list[str]:
    """The estimators' names of a pair's result, in its order."""
    return [r.name for r in result.estimators]


def rgb(color) -> np.ndarray:
    return np.asarray(color, np.uint8)


def ring(center: np.ndarray, radius: float = 12.0, n: int = 16) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n + 1)
    return center + radius * np.stack([np.cos(t), np.sin(t)], -1)


def log_marks(rec, path: str, strips: list, colors: list, radii: list, labels: list, arrows: list,
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


def epipole_marks(name: str, e: np.ndarray, size: tuple[int, int], unit: float = 1.0):
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
        return [ring(at, 1.3 * GLYPH_PX * unit, 20)]
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


def log_epipoles(rec, path: str, marks: list, clear: bool, size: tuple[int, int], extra=(), unit: float = 1.0) -> None:
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


SCALE_STEP = 28.0  # one residual bin of the scale below the images, screen px


def _scale_row(size_a: tuple[int, int], size_b: tuple[int, int]) -> tuple[float, float, float, float]:
    """The residual scale's row in image b's frame: (x of its left end, y, one bin's width, image px per screen px)."""
    unit = screen_unit(size_a)
    x, y = below_images(size_a, size_b, 46.0)
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
