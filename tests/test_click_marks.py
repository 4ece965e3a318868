"""What a click draws, sized and placed on screen: rings and lines in screen px (the same on a KITTI frame and a
3072-px photo), every clicked strip over a wider dark halo, and the residual label's box beside the partner, inside
the image, clear of the partner and, where the lines leave room, of every line drawn."""

from __future__ import annotations

import numpy as np
import pytest

import fviz
from fviz import interactive as I
from fviz.record.placement import screen_unit


def _fs(pair):
    result = fviz.inspect_pair(pair, ("8point", "ransac", "magsac"))
    return I.pair_fs(result, pair.size_a, pair.size_b)


@pytest.fixture(scope="module", params=["kitti-like", "3072x2048"])
def fs(request):
    pair = fviz.synthetic_pair(5, kind="temporal")
    if request.param == "3072x2048":
        import cv2

        s = 3072 / pair.size_a[0]
        S = np.array([[s, 0, 0.5 * s - 0.5], [0, s, 0.5 * s - 0.5], [0, 0, 1.0]])
        a, b = (cv2.resize(im, (3072, round(im.shape[0] * s))) for im in (pair.image_a, pair.image_b))
        pair = fviz.pair_from_images(a, b, K_a=S @ pair.K_a, K_b=S @ pair.K_b, R=pair.R, t=pair.t, name="big")
    return _fs(pair)


def test_rings_and_lines_are_sized_in_screen_px_over_a_halo(fs):
    u = screen_unit(fs.size_a)
    c = I.click(fs, "a", fs.x_a[10])
    marks = I.click_marks(fs, c)
    (ring,), _, (ring_r,), _ = marks["a"]
    assert np.allclose(np.linalg.norm(ring - c.point, axis=1), I.RING_PX * u)  # 7 screen px whatever the image size
    assert ring_r == pytest.approx(I.RING_LINE_PX * u)
    strips, colors, radii, _ = marks["b"]
    assert len(strips) == len(fs.names) + 1 and colors[-1] == I.RING_COLOR  # a line per F, the partner's ring
    assert radii[fs.names.index("gt")] == pytest.approx(I.GT_LINE_PX * u) and radii[1] == pytest.approx(I.LINE_PX * u)
    assert all(h > r for h, r in zip(I.halo_of(radii, u), radii))


def test_the_label_box_stays_off_the_partner_and_the_lines(fs):
    u = screen_unit(fs.size_a)
    clear, n = 0, 0
    for j in np.linspace(0, len(fs.x_a) - 1, 25).astype(int):
        c = I.click(fs, "a", fs.x_a[j])
        text = I.click_label(c)
        where, anchor = I.label_anchor(fs, c, text)
        rows = text.split("\n")
        half = 0.5 * u * np.array([I.LABEL_CHAR_PX * max(map(len, rows)), I.LABEL_ROW_PX * len(rows)])
        centre = anchor + [0.0, half[1]]
        w, h = fs.size(where)
        assert where == "b" and np.all(centre - half >= -1e-6) and np.all(centre + half <= [w, h])  # inside image b
        assert np.max(np.abs(centre - c.partner) - half) > 0  # the partner is not under it
        lines = c.lines[c.inside]
        ab = lines[:, :2] / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)
        d = np.abs(ab @ centre + lines[:, 2] / np.linalg.norm(lines[:, :2], axis=1)) - np.abs(ab) @ half
        clear += bool(np.all(d > 0))
        n += 1
    assert clear >= 0.8 * n, f"the label box crosses a line at {n - clear} of {n} clicks"
