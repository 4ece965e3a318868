"""Where both images and the marks that keep their size on screen sit in the 2D views (the root frame, image px).

Image b is drawn below image a (stacked) or right of it (side by side), whichever shows a pair of this
shape larger (:func:`side_by_side`: KITTI's 3.3:1 frames stack; 4:3, 3:2 and portrait photos sit side by side):
``b`` carries a translation by :func:`offset_b`, so one 2D view shows both and a match is one segment. Below
both images a footer holds the estimator's numbers and the residual scale; it and every mark meant to keep
its size on screen are scaled by :func:`screen_unit` (image px per screen px), so they read alike on a
1241x376 KITTI frame and a 3072x2048 photo. The entity paths these positions are logged under are
:mod:`fviz.record.layout`'s.
"""

from __future__ import annotations

import numpy as np

# The two images share one 2D view, stacked (b below a) or side by side (b right of a), whichever shows them
# larger in a view of ARRANGE_VIEW_PX screen px (between the overview's image view and an estimator tab's at
# 1600x1000): KITTI's 3.3:1 frames stack, 4:3, 3:2 and portrait photos sit side by side. Marks that must keep
# their size on screen (gap, footer, labels' offsets, keypoints, epipole glyphs) are given in screen px and
# scaled by :func:`screen_unit`, the image px per screen px in the narrowest view (VIEW_PX, the overview's).
VIEW_PX = (1140.0, 820.0)  # below the verdict line (~60 px)
ARRANGE_VIEW_PX = (1400.0, 820.0)
GAP_PX = 24.0  # screen px between image a and image b
FOOTER_PX = 76.0  # screen px below the images: the estimator's numbers and the residual scale (its end labels reach ~70)
MARGIN_PX = 12.0  # screen px left, right and above the images: an epipole's glyph on their border shows whole
KEYPOINT_RADIUS_PX = 2.0  # screen px


def _image_px_per_screen_px(size_a: tuple[int, int], side: bool, view: tuple[float, float]) -> float:
    """Image px per screen px when both images (image a's size) and the gap and footer fit ``view``."""
    (w, h), (vw, vh) = size_a, view
    vw, vh = vw - 2 * MARGIN_PX, vh - MARGIN_PX
    if side:
        return max(2 * w / (vw - GAP_PX), h / (vh - FOOTER_PX))
    return max(w / vw, 2 * h / (vh - GAP_PX - FOOTER_PX))


def side_by_side(size_a: tuple[int, int]) -> bool:
    """Whether image b sits right of image a rather than below it (see ARRANGE_VIEW_PX)."""
    return _image_px_per_screen_px(size_a, True, ARRANGE_VIEW_PX) < _image_px_per_screen_px(size_a, False, ARRANGE_VIEW_PX)


def screen_unit(size_a: tuple[int, int]) -> float:
    """Image px per screen px of the image views (at least the overview's, VIEW_PX): a mark of s screen px is
    s * screen_unit image px wide. ~1.09 on KITTI, ~5 on a 3072x2048 pair."""
    return _image_px_per_screen_px(size_a, side_by_side(size_a), VIEW_PX)


def keypoint_radius(size_a: tuple[int, int]) -> float:
    """Radius of the keypoints, in image pixels: KEYPOINT_RADIUS_PX on screen, whatever the images' size."""
    return KEYPOINT_RADIUS_PX * screen_unit(size_a)


def offset_b(size_a: tuple[int, int]) -> np.ndarray:
    """Where image b's origin sits in the shared 2D space: below image a, or right of it (:func:`side_by_side`)."""
    gap = GAP_PX * screen_unit(size_a)
    return np.array([size_a[0] + gap, 0.0]) if side_by_side(size_a) else np.array([0.0, size_a[1] + gap])


def images_extent(size_a: tuple[int, int], size_b: tuple[int, int]) -> tuple[float, float]:
    """(width, height) of both images as arranged, in the root frame (image px), footer left out."""
    right, bottom = offset_b(size_a) + size_b
    return max(size_a[0], right), max(size_a[1], bottom)


def below_images(size_a: tuple[int, int], size_b: tuple[int, int], drop_px: float) -> np.ndarray:
    """A point ``drop_px`` screen px below both images, centred under them, in image b's frame (the footer's
    marks are logged under b): (2,)."""
    w, h = images_extent(size_a, size_b)
    return np.array([w / 2, h + drop_px * screen_unit(size_a)]) - offset_b(size_a)


def view_extent(sizes) -> tuple[float, float, float]:
    """(width, height with the footer, margin) that the images' views frame, in the root frame: of one pair's
    ``(size_a, size_b)``, or the largest over many pairs' ``[(size_a, size_b), ...]`` (pairs of several sizes in one
    recording, one blueprint: each pair fits, drawn from the top left)."""
    many = [sizes] if np.ndim(sizes[0]) == 1 else list(sizes)
    return (max(images_extent(*s)[0] for s in many), max(images_extent(*s)[1] + FOOTER_PX * screen_unit(s[0]) for s in many),
            max(MARGIN_PX * screen_unit(s[0]) for s in many))


def match_points(x_a: np.ndarray, x_b: np.ndarray, size_a: tuple[int, int]) -> np.ndarray:
    """The positions of ``layout.matches``: (N, 2), (N, 2) -> (2N, 2), b's shifted by :func:`offset_b`."""
    return np.concatenate([x_a, x_b + offset_b(size_a)])
