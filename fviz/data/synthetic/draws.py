"""The stream of draws a scene is made from: every scene parameter is a fixed draw index of a counter-based
generator (splitmix64 of (seed, index) in int64 torch ops), so there is no Python work per seed, and the same seed
gives the same scene alone, inside any batch, and on the CPU or a GPU.  Variable parts have a fixed size with masks
(every box slot exists, and all tries of a box's spot are drawn at once), so the stream depends on the config's
sizes only."""

from __future__ import annotations

import math

import numpy as np
import torch

from fviz.data.synthetic.config import SceneConfig

SCENE_SALT = 0x5CE7_E5A1  # added to the seed before its stream of draws
PLACEMENT_TRIES = 8  # rejection-sampling tries for the spot of a box

# Materials: (texel size in metres, texture gain, brightness range).
_ROAD = (0.025, 0.10, (0.25, 0.45))
_FACADE = (0.03, 0.16, (0.35, 0.75))
_BOX = (0.015, 0.18, (0.20, 0.80))
_X, _Y, _Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)


def _i64(x: int) -> int:
    """An unsigned 64-bit constant as the int64 with the same bits."""
    x &= (1 << 64) - 1
    return x - (1 << 64) if x >> 63 else x


GOLDEN, _MIX1, _MIX2 = _i64(0x9E3779B97F4A7C15), _i64(0xBF58476D1CE4E5B9), _i64(0x94D049BB133111EB)


def shr(z: torch.Tensor, k: int) -> torch.Tensor:
    """Logical right shift of int64 bits (torch's >> is arithmetic)."""
    return (z >> k) & ((1 << (64 - k)) - 1)


def mix64(z: torch.Tensor) -> torch.Tensor:
    """splitmix64's finaliser on int64 tensors (multiplications wrap modulo 2**64)."""
    z = (z ^ shr(z, 30)) * _MIX1
    z = (z ^ shr(z, 27)) * _MIX2
    return z ^ shr(z, 31)


class DrawLayout:
    """Where each scene parameter sits in a seed's stream of draws, and its uniform range."""

    def __init__(self) -> None:
        self.slots: dict[str, tuple[int, tuple[int, ...]]] = {}
        self.lo: list[float] = []
        self.hi: list[float] = []

    def add(self, name: str, shape: tuple[int, ...], lo=0.0, hi=1.0) -> None:
        self.slots[name] = (len(self.lo), shape)
        self.lo += np.broadcast_to(np.asarray(lo, np.float64), shape).ravel().tolist()
        self.hi += np.broadcast_to(np.asarray(hi, np.float64), shape).ravel().tolist()

    def get(self, x: torch.Tensor, name: str) -> torch.Tensor:
        """Columns of ``name`` in x (B, D) -> (B, *shape)."""
        start, shape = self.slots[name]
        return x[:, start : start + math.prod(shape)].reshape(x.shape[0], *shape)


def slot_kinds(cfg: SceneConfig) -> list[tuple[tuple, tuple, tuple]]:
    """(material, e1, e2) of every rectangle slot of a scene, in slot order.

    Slots: left facades (n), left junction walls (n - 1), the same on the right, road, end wall
    (4 n fixed planes), then 5 faces (x0, x1, z0, z1, top) of each of the 2 n_boxes boxes
    (body, cabin, body, cabin, ...).
    """
    n = cfg.facade_segments
    side = [(_FACADE, _Z, _Y)] * n + [(_FACADE, _X, _Y)] * (n - 1)
    faces = [(_BOX, _Z, _Y), (_BOX, _Z, _Y), (_BOX, _X, _Y), (_BOX, _X, _Y), (_BOX, _X, _Z)]
    return side + side + [(_ROAD, _X, _Z), (_FACADE, _X, _Y)] + faces * (2 * cfg.n_boxes)


def draw_layout(cfg: SceneConfig) -> DrawLayout:
    """The draws of one scene (the stream depends on the config's sizes only)."""
    n, nb, T = cfg.facade_segments, cfg.n_boxes, PLACEMENT_TRIES
    d2r, rot = math.pi / 180.0, cfg.rotation_deg * math.pi / 180.0
    z_min = cfg.forward_range[1] + 2.0  # boxes start beyond the furthest camera b
    kinds = slot_kinds(cfg)
    L = DrawLayout()
    L.add("h", (), 1.55, 1.75)  # camera height: the road is the plane y = h
    L.add("far", (), 60.0, 140.0)  # the street ends with a wall at z = far
    L.add("cuts", (n - 1,))  # facade segment ends, uniform in [5, far - 10]
    L.add("base", (2,), 3.0, 7.0)  # lateral distance of the facades (left, right) ...
    L.add("dist", (2, n), 0.0, 2.5)  # ... plus this per segment
    L.add("tall", (2, n), 5.0, 18.0)
    L.add("end_h", (), 6.0, 20.0)
    L.add("sky", (), 0.75, 0.95)
    L.add("mount", (3,), [-2.0 * d2r, -d2r, -d2r], [2.0 * d2r, d2r, d2r])  # camera yaw, pitch, roll
    L.add("motion", (3,), [-rot, -0.3 * rot, -0.3 * rot], [rot, 0.3 * rot, 0.3 * rot])  # of camera b
    L.add("fwd", (), *cfg.forward_range)
    L.add("lift", (), -0.02, 0.02)
    L.add("noise", (2,))  # raw bits: the noise index of views a and b
    L.add("car", (nb,))  # < 0.6: a car (body + cabin), else a crate
    L.add("car_dims", (nb, 3), [1.6, 3.6, 0.8], [1.9, 4.8, 1.1])  # width, length, height
    L.add("crate_dims", (nb, 3), 0.5, 2.5)
    L.add("try_x", (nb, T))  # spot tries: x in the free width, z in [z_min, z_min + 30]
    L.add("try_z", (nb, T), z_min, z_min + 30.0)
    L.add("cabin", (nb, 4), [0.1, 0.45, 0.4, 0.25], [0.2, 0.55, 0.6, 0.35])  # width cut, length, height, offset
    gain = np.array([[m[1] * cfg.texture_contrast] for m, _, _ in kinds]).reshape(-1, 1)
    bright = np.array([m[2] for m, _, _ in kinds]).reshape(-1, 2)
    tex_lo = np.column_stack([np.full(len(kinds), 0.7), np.full(len(kinds), -math.pi), -np.ones(len(kinds)),
                              -np.ones(len(kinds)), 0.75 * gain[:, 0], bright[:, 0]])
    tex_hi = np.column_stack([np.full(len(kinds), 1.4), np.full(len(kinds), math.pi), np.ones(len(kinds)),
                              np.ones(len(kinds)), 1.25 * gain[:, 0], bright[:, 1]])
    L.add("tex", (len(kinds), 6), tex_lo, tex_hi)  # scale, angle, offset x, offset y, gain, brightness
    # appended draws: earlier ones keep their place, so existing seeds keep their scenes
    L.add("exposure", (2,), -1.0, 1.0)  # per view, scaled by cfg.exposure
    L.add("straight", ())  # < straight_fraction: a straight-driving scene
    return L
