"""Synthetic KITTI-like image pairs with exact ground truth (F, cameras and correspondences).

Scenes are piecewise planar streets: a road, building facades on both sides (parallel to the
driving direction, a few segments per side joined by short walls), a wall closing the street
far ahead, and axis-aligned boxes and cars (a car is a body box plus a cabin box).  Every plane
is a bounded rectangle carrying a texture fixed to its surface (a shared bank of 1/f noise and
random blocks, placed with a random scale, rotation and offset per plane).

Frames: the *street* frame has x right, y down (the road is the plane y = h), z along the street,
and its origin at the centre of camera a.  Camera frames are OpenCV's (x right, y down, z forward);
a camera maps street points by X_cam = R_cw (X_street - C).  The motion X_b = R X_a + t goes from
camera a to camera b and F (x_b^T F x_a = 0, pixels, OpenCV origin) is K^-T [t]x R K^-1 with
unit Frobenius norm and the sign of :func:`fviz.geometry.normalize`'s 'fbn'.

The modules, in the order a pair is made: config (:class:`SceneConfig`, KITTI's camera), draws (the
counter-based stream of each seed's parameters), consts (the constant tensors per config and device),
scene (streets, boxes and cameras from the draws), elementwise (exact 3-vector maths), raster (ray
casting the planes to pixels), appearance (texture and noise banks, blur), batch (:func:`render_batch`,
the training set's generator, CUDA graphs) and pair_source (:func:`synthetic_pair`, one pair with
exact correspondences).
"""

from fviz.data.synthetic.appearance import noise_bank, texture_bank
from fviz.data.synthetic.batch import render_batch
from fviz.data.synthetic.config import KITTI_K, KITTI_SIZE, SceneConfig, intrinsics
from fviz.data.synthetic.pair_source import synthetic_pair

__all__ = [
    "KITTI_K",
    "KITTI_SIZE",
    "SceneConfig",
    "intrinsics",
    "noise_bank",
    "render_batch",
    "synthetic_pair",
    "texture_bank",
]
