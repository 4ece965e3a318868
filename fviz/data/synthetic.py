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

Scene sampling is batched tensor code that runs on the rendering device: every scene parameter is
a fixed draw index of a counter-based generator (splitmix64 of (seed, index) in int64 torch ops),
so there is no Python work per seed, and the same seed gives the same scene alone, inside any
batch, and on the CPU or a GPU.  Variable parts have a fixed size with masks: every box slot
exists (a box that found no free spot, or the cabin slot of a crate, is an invalid plane), and
the rejection sampling of box spots draws all tries at once.  The parameter maths uses only
+ - * / sqrt (sin and cos are a polynomial), one elementwise op at a time, so the scene is
bit-identical on any device and for any batch size.

Rendering is exact ray casting against all planes, vectorised in torch.  For a plane, 1/depth and
the four "ray inside edge k" tests are affine functions of the pixel (u, v), so along one image row
each plane covers one interval of u.  Because the rectangles of a scene never cross (they may only
touch along edges), the nearest plane along a row can only change at an interval end: the renderer
sorts the interval ends of a row, finds the nearest plane at the middle of each piece (rows x pieces
x planes, cheap) and spreads the winner over the pixels of the piece.  Correspondences use the
direct form (rays x planes, nearest positive hit inside the rectangle) in float64.  Pixel noise is
read from a fixed bank of Gaussian values at a per-view pseudo-random affine index.

On a CUDA device, :func:`render_batch` has no host <-> device synchronisation and no Python loop
over the batch: it records the whole batch as a CUDA graph per (config, batch size, device) the
first time (at most ``MAX_GRAPHS`` kept, each holding its work memory; FVIZ_SYNTHETIC_CUDA_GRAPHS=0
runs eagerly) and replays it afterwards, on a side stream of its own that does not wait for the
caller's queued work (FVIZ_SYNTHETIC_SIDE_STREAM=0: on the caller's stream), so the rendering of
the next batch can run on the GPU alongside the current training step; the caller's stream waits
for the results.  A GPU renders the same images as the CPU (seen bit-identical on an H100; the
texture interpolation could in principle round differently).
"""

from __future__ import annotations

import functools
import math
import numbers
import os
import threading
import warnings
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np
import torch
import torch.nn.functional as tnf

from fviz.data.pair import Pair, PairId
from fviz.errors import FvizError

KITTI_SIZE = (1242, 375)  # (width, height) of KITTI odometry grey images
KITTI_K = (718.856, 718.856, 607.1928, 185.2157)  # fx, fy, cx, cy of KITTI odometry sequence 00
TEXTURE_SIZE = 1024  # texels per side of the shared texture bank
NOISE_BANK_BITS = 19  # pixel-noise bank: 2**19 standard normal values (2 MB: cache-sized; > 1242 x 375 pixels)
SCENE_SALT = 0x5CE7_E5A1  # added to the seed before its stream of draws
POINTS_SEED_SALT = 0xC0FF_EE11  # generator seed = seed ^ salt for the pixels sampled for correspondences
VISIBLE_RTOL = 1e-6  # relative depth tolerance of the visibility test in image b
CHUNK_PIXELS = 1 << 17  # pixels shaded per step on the CPU (keeps the work buffers in cache)
GPU_CHUNK_PIXELS = 1 << 23  # pixels shaded per step on a GPU (bounds the work buffers)
PLACEMENT_TRIES = 8  # rejection-sampling tries for the spot of a box
MAX_GRAPHS = 4  # CUDA graphs kept (least recently used dropped first)
CUDA_GRAPHS = os.environ.get("FVIZ_SYNTHETIC_CUDA_GRAPHS", "1").strip() not in ("0", "false", "no", "off")
SIDE_STREAM = os.environ.get("FVIZ_SYNTHETIC_SIDE_STREAM", "1").strip() not in ("0", "false", "no", "off")

# Materials: (texel size in metres, texture gain, brightness range).
_ROAD = (0.025, 0.10, (0.25, 0.45))
_FACADE = (0.03, 0.16, (0.35, 0.75))
_BOX = (0.015, 0.18, (0.20, 0.80))
_X, _Y, _Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)


# --------------------------------------------------------------------------------------- config


@dataclass(frozen=True)
class SceneConfig:
    """Difficulty knobs of the synthetic scenes (validated on construction, errors name the field).

    width, height: image size in pixels; the KITTI intrinsics are scaled with it.
    stereo: rectified stereo pairs (camera b is ``baseline`` metres to the right, R = I)
        instead of temporal pairs (camera b moved forward by ``forward_range`` metres, rotated
        by up to ``rotation_deg`` in yaw and 0.3 * ``rotation_deg`` in pitch and roll).
    n_boxes: boxes and cars on the street (occluders); facade_segments: buildings per side.
    texture_contrast: scales every surface texture; texture_frequency: texture detail per metre.
    noise_sigma: Gaussian pixel noise in grey levels (0..255); blur_sigma: Gaussian blur in pixels.
    exposure: each view's brightness is scaled by 1 + exposure * u, u uniform in [-1, 1] per view
        (auto-exposure differences between frames and cameras).
    straight_fraction: the share of temporal scenes that drive (almost) straight: their rotation is
        a tenth of the drawn one.  KITTI-like motion: ``rotation_deg = 3.5`` (yaw rates up to about
        3.5 deg per frame) with ``straight_fraction = 0.5`` (most frames go straight ahead).
    n_points: pixels of image a sampled for the exact correspondences (``synthetic_pair``).
    """

    width: int = KITTI_SIZE[0]
    height: int = KITTI_SIZE[1]
    stereo: bool = False
    baseline: float = 0.54
    forward_range: tuple[float, float] = (0.3, 2.0)
    rotation_deg: float = 2.0
    n_boxes: int = 3
    facade_segments: int = 2
    texture_contrast: float = 1.0
    texture_frequency: float = 1.0
    noise_sigma: float = 1.0
    blur_sigma: float = 0.0
    n_points: int = 2000
    exposure: float = 0.0
    straight_fraction: float = 0.0

    def __post_init__(self) -> None:
        def bad(name: str, rule: str) -> FvizError:
            return FvizError(f"SceneConfig.{name}: must be {rule} (got {getattr(self, name)!r})")

        def number(name: str, lo: float, hi: float, lo_open: bool = False) -> None:
            v = getattr(self, name)
            ok = isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)
            if not ok or not (lo < v if lo_open else lo <= v) or v > hi:
                raise bad(name, f"a number in {'(' if lo_open else '['}{lo}, {hi}]")

        def integer(name: str, lo: int, hi: int) -> None:
            v = getattr(self, name)
            if not isinstance(v, numbers.Integral) or isinstance(v, bool) or not lo <= v <= hi:
                raise bad(name, f"an integer in [{lo}, {hi}]")

        integer("width", 32, 8192)
        integer("height", 32, 8192)
        if not isinstance(self.stereo, (bool, np.bool_)):
            raise bad("stereo", "a bool")
        number("baseline", 0.0, 10.0, lo_open=True)
        fr = self.forward_range
        if (
            not isinstance(fr, (tuple, list))
            or len(fr) != 2
            or not all(isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x) for x in fr)
            or not 0.0 < fr[0] <= fr[1] <= 5.0
        ):
            raise bad("forward_range", "a pair (lo, hi) of metres with 0 < lo <= hi <= 5")
        number("rotation_deg", 0.0, 30.0)
        integer("n_boxes", 0, 16)
        integer("facade_segments", 1, 8)
        number("texture_contrast", 0.0, 10.0)
        number("texture_frequency", 0.05, 20.0)
        number("noise_sigma", 0.0, 100.0)
        number("blur_sigma", 0.0, 10.0)
        number("exposure", 0.0, 0.9)
        number("straight_fraction", 0.0, 1.0)
        integer("n_points", 1, 10_000_000)


def intrinsics(width: int = KITTI_SIZE[0], height: int = KITTI_SIZE[1]) -> np.ndarray:
    """KITTI's K scaled to an image of ``width`` x ``height`` (pixel centres at integers).  -> (3, 3)."""
    fx, fy, cx, cy = KITTI_K
    sx, sy = width / KITTI_SIZE[0], height / KITTI_SIZE[1]
    return np.array([[fx * sx, 0.0, (cx + 0.5) * sx - 0.5], [0.0, fy * sy, (cy + 0.5) * sy - 0.5], [0.0, 0.0, 1.0]])



def _canonical(cfg: SceneConfig) -> SceneConfig:
    """The config with a tuple forward_range (hashable: configs key the caches)."""
    if not isinstance(cfg, SceneConfig):
        raise FvizError(f"config: must be a SceneConfig (got {type(cfg).__name__})")
    return cfg if isinstance(cfg.forward_range, tuple) else replace(cfg, forward_range=tuple(cfg.forward_range))


# ------------------------------------------------------------------- counter-based random draws


def _i64(x: int) -> int:
    """An unsigned 64-bit constant as the int64 with the same bits."""
    x &= (1 << 64) - 1
    return x - (1 << 64) if x >> 63 else x


_GOLDEN, _MIX1, _MIX2 = _i64(0x9E3779B97F4A7C15), _i64(0xBF58476D1CE4E5B9), _i64(0x94D049BB133111EB)


def _shr(z: torch.Tensor, k: int) -> torch.Tensor:
    """Logical right shift of int64 bits (torch's >> is arithmetic)."""
    return (z >> k) & ((1 << (64 - k)) - 1)


def _mix64(z: torch.Tensor) -> torch.Tensor:
    """splitmix64's finaliser on int64 tensors (multiplications wrap modulo 2**64)."""
    z = (z ^ _shr(z, 30)) * _MIX1
    z = (z ^ _shr(z, 27)) * _MIX2
    return z ^ _shr(z, 31)


class _Layout:
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


def _slot_kinds(cfg: SceneConfig) -> list[tuple[tuple, tuple, tuple]]:
    """(material, e1, e2) of every rectangle slot of a scene, in slot order.

    Slots: left facades (n), left junction walls (n - 1), the same on the right, road, end wall
    (4 n fixed planes), then 5 faces (x0, x1, z0, z1, top) of each of the 2 n_boxes boxes
    (body, cabin, body, cabin, ...).
    """
    n = cfg.facade_segments
    side = [(_FACADE, _Z, _Y)] * n + [(_FACADE, _X, _Y)] * (n - 1)
    faces = [(_BOX, _Z, _Y), (_BOX, _Z, _Y), (_BOX, _X, _Y), (_BOX, _X, _Y), (_BOX, _X, _Z)]
    return side + side + [(_ROAD, _X, _Z), (_FACADE, _X, _Y)] + faces * (2 * cfg.n_boxes)


def _layout(cfg: SceneConfig) -> _Layout:
    """The draws of one scene (the stream depends on the config's sizes only)."""
    n, nb, T = cfg.facade_segments, cfg.n_boxes, PLACEMENT_TRIES
    d2r, rot = math.pi / 180.0, cfg.rotation_deg * math.pi / 180.0
    z_min = cfg.forward_range[1] + 2.0  # boxes start beyond the furthest camera b
    kinds = _slot_kinds(cfg)
    L = _Layout()
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


class _Consts:
    """Per (config, device): the draw layout and every constant tensor the generator needs.

    Made outside any CUDA graph capture (the graph keeps references to these tensors).
    """

    def __init__(self, cfg: SceneConfig, device: torch.device) -> None:
        f64, i64 = torch.float64, torch.int64
        n, nb, H, W = cfg.facade_segments, cfg.n_boxes, cfg.height, cfg.width
        self.layout = L = _layout(cfg)
        lo, hi = np.array(L.lo), np.array(L.hi)
        as_t = functools.partial(torch.tensor, device=device)
        self.lo, self.span = as_t(lo, dtype=f64), as_t(hi - lo, dtype=f64)
        self.steps = (torch.arange(1, len(lo) + 1, dtype=i64) * _GOLDEN).to(device)  # wraps like splitmix64
        kinds = _slot_kinds(cfg)
        self.kscale = as_t([2.0 * cfg.texture_frequency / (TEXTURE_SIZE * m[0]) for m, _, _ in kinds], dtype=f64)
        self.e1 = as_t([e1 for _, e1, _ in kinds], dtype=f64).reshape(-1, 3)
        self.e2 = as_t([e2 for _, _, e2 in kinds], dtype=f64).reshape(-1, 3)
        self.side = as_t([[-1.0], [1.0]], dtype=f64)
        self.eye = torch.eye(3, dtype=f64, device=device)
        self.fixed_idx = torch.arange(4 * n, dtype=i64, device=device)
        self.box_x = torch.arange(2 * nb, dtype=i64, device=device) * 5 + 4 * n  # slot of face x0 of each box
        self.box_z, self.box_top = self.box_x + 2, self.box_x + 4
        self.tries = torch.arange(PLACEMENT_TRIES, dtype=i64, device=device)
        K = intrinsics(W, H)
        self.K = as_t(K, dtype=f64)
        self.K_inv = as_t(np.array([[1 / K[0, 0], 0, -K[0, 2] / K[0, 0]], [0, 1 / K[1, 1], -K[1, 2] / K[1, 1]], [0, 0, 1]]),
                          dtype=f64)
        self.kinv = (1 / K[0, 0], -K[0, 2] / K[0, 0], 1 / K[1, 1], -K[1, 2] / K[1, 1])
        self.rows = torch.arange(H, dtype=f64, device=device)[:, None, None]
        self.u = torch.arange(W, dtype=torch.float32, device=device)
        self.u_int = torch.arange(W, dtype=torch.int32, device=device)
        self.pix = torch.arange(H * W, dtype=torch.int32, device=device)
        self.bank = texture_bank(str(device))
        self.noise = noise_bank(str(device)) * (cfg.noise_sigma / 255.0) if cfg.noise_sigma > 0 else None  # grey levels


@functools.lru_cache(maxsize=8)
def _consts(cfg: SceneConfig, device: torch.device) -> _Consts:
    return _Consts(cfg, device)


# ----------------------------------------------------------------- exact small-matrix helpers


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    a0, a1, a2 = a.unbind(-1)
    b0, b1, b2 = b.unbind(-1)
    return torch.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], -1)


def _mv(A: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """A (..., 3, 3) times x (..., 3), broadcasting, as separate elementwise ops (no BLAS)."""
    return A[..., 0] * x[..., 0:1] + A[..., 1] * x[..., 1:2] + A[..., 2] * x[..., 2:3]


def _mm(A: torch.Tensor, B: torch.Tensor) -> torch.Tensor:
    """A (..., 3, 3) @ B (..., 3, 3), broadcasting, as separate elementwise ops (no BLAS)."""
    return A[..., :, 0:1] * B[..., 0:1, :] + A[..., :, 1:2] * B[..., 1:2, :] + A[..., :, 2:3] * B[..., 2:3, :]


def _sincos(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """sin and cos of |x| <= 4 from + - * only (the same bits on every device and batch size).

    Taylor polynomials at x / 8 (error < 1e-18), then three angle doublings.
    """
    y = x * 0.125
    y2 = y * y
    s = y * (1.0 + y2 * (-1 / 6 + y2 * (1 / 120 + y2 * (-1 / 5040 + y2 * (1 / 362880 + y2 * (-1 / 39916800 + y2 / 6227020800))))))
    c = 1.0 + y2 * (-0.5 + y2 * (1 / 24 + y2 * (-1 / 720 + y2 * (1 / 40320 + y2 * (-1 / 3628800
                                                                       + y2 * (1 / 479001600 - y2 / 87178291200))))))
    for _ in range(3):
        s, c = 2.0 * s * c, (c - s) * (c + s)
    return s, c


def _rotation(s: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Ry(yaw) @ Rx(pitch) @ Rz(roll) from sines and cosines (..., 3) of (yaw, pitch, roll).  -> (..., 3, 3).

    y points down, so a positive yaw turns right.
    """
    sy, sp, sr = s.unbind(-1)
    cy, cp, cr = c.unbind(-1)
    spsr, spcr = sp * sr, sp * cr
    rows = [cy * cr + sy * spsr, sy * spcr - cy * sr, sy * cp,
            cp * sr, cp * cr, -sp,
            cy * spsr - sy * cr, sy * sr + cy * spcr, cy * cp]  # fmt: skip
    return torch.stack(rows, -1).reshape(*s.shape[:-1], 3, 3)


# ------------------------------------------------------------------------------- scene sampling


def _sample(seeds: torch.Tensor, cfg: SceneConfig, c: _Consts) -> dict[str, torch.Tensor]:  # noqa: PLR0915 (one batched scene draw, step by step as the docstring tells it)
    """Draw the street scenes and camera pairs of ``seeds`` (B,) int64, on their device, float64.

    Returns planes (2 B, P, 20): per view (all a's, then all b's) the P rectangles it needs, as
    origin (3), e1 (3), e2 (3) (street frame), size (2), texture map (2 x 3: plane coordinates
    (s, r, 1) in metres -> grid_sample coordinates), shade (gain, brightness) and valid (0 / 1);
    R_cw (2 B, 3, 3), C (2 B, 3): the cameras; sky (2 B,); noise_mul, noise_add (2 B,) int32: the
    affine noise index of each view (see noise_bank); R (B, 3, 3), t (B, 3): the motion a -> b.
    """
    L, B, f64 = c.layout, seeds.shape[0], torch.float64
    n, nb, T = cfg.facade_segments, cfg.n_boxes, PLACEMENT_TRIES
    bits = _mix64(_mix64(seeds + SCENE_SALT)[:, None] + c.steps)  # (B, D): splitmix64 stream of each seed
    u = c.lo + c.span * (_shr(bits, 11).to(f64) * 2.0**-53)  # uniform in [lo, hi)
    g = functools.partial(L.get, u)

    # street: facades of both sides (segments and junction walls), road, end wall; (B, k, 5) = origin, size
    h, far = g("h")[:, None], g("far")[:, None]
    z = [torch.full_like(far, -6.0), far]
    if n > 1:
        z.insert(1, (5.0 + (far - 15.0) * g("cuts")).sort(-1).values)
    z = torch.cat(z, 1)  # (B, n + 1) segment ends along the street
    dist = g("base")[..., None] + g("dist")  # (B, 2, n) lateral distance (left, right)
    tall = g("tall")
    x = c.side * dist  # signed x of each segment
    hh = h[..., None]
    fac = torch.stack([x, hh - tall, z[:, None, :-1].expand(B, 2, n), (z[:, 1:] - z[:, :-1])[:, None].expand(B, 2, n), tall], -1)
    # junction walls: the end of the building that sticks out further into the street
    xa, xb = x[..., :-1], x[..., 1:]
    jh = torch.where(dist[..., :-1] < dist[..., 1:], tall[..., :-1], tall[..., 1:])
    jun = torch.stack([torch.minimum(xa, xb), hh - jh, z[:, None, 1:-1].expand(B, 2, n - 1), (xa - xb).abs(), jh], -1)
    dl, dr = dist[:, 0], dist[:, 1]
    wl, wr, end_h = dl.amax(-1, keepdim=True), dr.amax(-1, keepdim=True), g("end_h")[:, None]
    road = torch.cat([-wl, h, z[:, :1], wl + wr, far + 6.0], 1)
    end = torch.cat([-dl[:, -1:], h - end_h, far, dl[:, -1:] + dr[:, -1:], end_h], 1)
    geo = [torch.cat([fac, jun], 2).reshape(B, 4 * n - 2, 5), road[:, None], end[:, None]]
    ok = [torch.ones(B, 4 * n, dtype=torch.bool, device=u.device)]

    if nb:  # cars (body + cabin) and crates (body + invalid cabin slot) that do not overlap
        z_min = cfg.forward_range[1] + 2.0
        xl, xr = 0.3 - dl.amin(-1, keepdim=True), dr.amin(-1, keepdim=True) - 0.3  # (B, 1) free width
        car = g("car") < 0.6
        w, l, bh = torch.where(car[..., None], g("car_dims"), g("crate_dims")).unbind(-1)  # (B, nb)
        x0c = xl[..., None] + (xr[..., None] - w[..., None] - xl[..., None]) * g("try_x")  # (B, nb, T)
        z0c = g("try_z")
        fits = (xl[..., None] <= x0c) & (x0c + w[..., None] <= xr[..., None])
        foot = u.new_zeros(B, nb, 4)  # x0, x1, z0, z1 of the boxes placed so far
        placed = torch.zeros(B, nb, dtype=torch.bool, device=u.device)
        for j in range(nb):  # rejection sampling: the first try clear of the boxes before
            xj, zj, wj, lj = x0c[:, j], z0c[:, j], w[:, j : j + 1], l[:, j : j + 1]
            free = fits[:, j]
            if j:
                f = foot[:, None, :j]  # (B, 1, j, 4)
                apart = (
                    (xj[..., None] > f[..., 1] + 0.3)
                    | ((xj + wj)[..., None] < f[..., 0] - 0.3)
                    | (zj[..., None] > f[..., 3] + 0.3)
                    | ((zj + lj)[..., None] < f[..., 2] - 0.3)
                    | ~placed[:, None, :j]
                )
                free = free & apart.all(-1)
            first = torch.where(free, c.tries, T).amin(-1, keepdim=True)  # (B, 1), T: no free try
            found = first < T
            sel = first.clamp(max=T - 1)
            x0 = torch.where(found, xj.gather(1, sel), 0.0)
            z0 = torch.where(found, zj.gather(1, sel), z_min)
            foot[:, j] = torch.cat([x0, x0 + wj, z0, z0 + lj], 1)
            placed[:, j] = found[:, 0]
        x0, x1, z0, z1 = foot.unbind(-1)
        cu = g("cabin")
        cw, cl, top = w - cu[..., 0], l * cu[..., 1], h - bh
        cx0, cz0 = x0 + (w - cw) * 0.5, z0 + l * cu[..., 3]
        lo = torch.stack([torch.stack([x0, top, z0], -1), torch.stack([cx0, top - cu[..., 2], cz0], -1)], 2)
        hi = torch.stack([torch.stack([x1, h.expand(B, nb), z1], -1), torch.stack([cx0 + cw, top, cz0 + cl], -1)], 2)
        lo, hi = lo.reshape(B, 2 * nb, 3), hi.reshape(B, 2 * nb, 3)  # body, cabin, body, cabin, ...
        bx0, by0, bz0 = lo.unbind(-1)
        bx1, by1, bz1 = hi.unbind(-1)
        bw, bt, bl = bx1 - bx0, by1 - by0, bz1 - bz0
        faces = torch.stack([
            torch.stack([bx0, bx1, bx0, bx0, bx0], -1),
            by0[..., None].expand(B, 2 * nb, 5),
            torch.stack([bz0, bz0, bz0, bz1, bz0], -1),
            torch.stack([bl, bl, bw, bw, bw], -1),
            torch.stack([bt, bt, bt, bt, bl], -1),
        ], -1)  # fmt: skip
        geo.append(faces.reshape(B, 10 * nb, 5))
        ok.append(torch.stack([placed, placed & car], -1)[..., None].expand(B, nb, 2, 5).reshape(B, 10 * nb))
    geo = torch.cat(geo, 1)  # (B, Rt, 5)
    valid = torch.cat(ok, 1) & (geo[..., 3] > 1e-3) & (geo[..., 4] > 1e-3)

    # textures, camera mount and motion: all angles in one sincos
    tex = g("tex")  # (B, Rt, 6)
    Rt = tex.shape[1]
    motion = g("motion")
    if cfg.straight_fraction > 0:
        motion = motion * torch.where(g("straight") < cfg.straight_fraction, 0.1, 1.0)[:, None]
    sin, cos = _sincos(torch.cat([tex[..., 1], g("mount"), motion, motion[:, :1] * 0.5], 1))
    scale = c.kscale / tex[..., 0]
    st, ct = sin[:, :Rt] * scale, cos[:, :Rt] * scale
    tmap = torch.stack([ct, -st, tex[..., 2], st, ct, tex[..., 3]], -1)  # rows (c, -s, ox), (s, c, oy)
    rot = _rotation(sin[:, Rt : Rt + 6].reshape(B, 2, 3), cos[:, Rt : Rt + 6].reshape(B, 2, 3))
    R_aw = rot[:, 0]  # camera mount
    if cfg.stereo:
        Q = c.eye.expand(B, 3, 3)
        zero = u.new_zeros(B)
        c_b = torch.stack([zero + cfg.baseline, zero, zero], -1)
    else:  # car-like: drive forward along an arc (translation at half the yaw), small pitch and roll
        Q = rot[:, 1]
        fwd = g("fwd")
        c_b = torch.stack([fwd * sin[:, -1], fwd * g("lift"), fwd * cos[:, -1]], -1)
    R = Q.transpose(1, 2)  # X_b = Q^T (X_a - c_b), with Q the axes and c_b the centre of b in frame a
    t = -_mv(R, c_b)
    R_cw = torch.stack([R_aw, _mm(R, R_aw)])  # (2, B, 3, 3)
    C = torch.stack([torch.zeros_like(c_b), _mv(R_aw.transpose(1, 2), c_b)])  # (2, B, 3)

    # the planes each view needs: the fixed ones and the 3 faces of each box towards its camera
    fields = torch.cat(
        [geo[..., :3], c.e1.expand(B, Rt, 3), c.e2.expand(B, Rt, 3), geo[..., 3:], tmap, tex[..., 4:], valid[..., None].to(f64)], -1
    )  # (B, Rt, 20)
    idx = c.fixed_idx.expand(2, B, 4 * n)
    if nb:
        face = torch.stack([
            c.box_x + (C[..., 0:1] > hi[..., 0]),
            c.box_z + (C[..., 2:3] > hi[..., 2]),
            c.box_top.expand(2, B, 2 * nb),
        ], -1)  # fmt: skip
        idx = torch.cat([idx, face.reshape(2, B, 6 * nb)], -1)
    P = idx.shape[-1]
    planes = fields.expand(2, B, Rt, 20).gather(2, idx[..., None].expand(2, B, P, 20))
    keys = _shr(L.get(bits, "noise"), 20).t()  # (2, B) 44 bits per view
    mask = (1 << NOISE_BANK_BITS) - 1
    return {
        "planes": planes.reshape(2 * B, P, 20),
        "R_cw": R_cw.reshape(2 * B, 3, 3),
        "C": C.reshape(2 * B, 3),
        "sky": g("sky").repeat(2),
        "gain": (1.0 + cfg.exposure * g("exposure")).t().reshape(2 * B),  # views a (first B), then b
        "noise_mul": ((keys & mask) | 1).reshape(2 * B).to(torch.int32),
        "noise_add": (_shr(keys, NOISE_BANK_BITS) & mask).reshape(2 * B).to(torch.int32),
        "R": R,
        "t": t,
    }


# ------------------------------------------------------------------------ planes -> pixel maps


def _plane_coefficients(
    planes: torch.Tensor, R_cw: torch.Tensor, C: torch.Tensor, kinv: tuple[float, float, float, float]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per-plane affine functions of the pixel, for N views.

    planes (N, P, 20) (see _sample), R_cw (N, 3, 3), C (N, 3), kinv = (1/fx, -cx/fx, 1/fy, -cy/fy).
    Returns coef (N, P, 7, 3) float64, shade (N, P, 2), valid (N, P).  Row k of coef is (a, b, c)
    with value a u + b v + c at pixel (u, v): rows 0-3 are >= 0 iff the ray is inside edge k of the
    rectangle (the cone over a convex polygon), row 4 is 1/depth (z), rows 5-6 are the grid_sample
    texture coordinates times 1/depth.
    """
    Rm = R_cw[:, None]
    o = _mv(Rm, planes[..., 0:3] - C[:, None])  # (N, P, 3) in camera coordinates
    e1, e2 = _mv(Rm, planes[..., 3:6]), _mv(Rm, planes[..., 6:9])
    s1, s2 = e1 * planes[..., 9:10], e2 * planes[..., 10:11]
    c1 = o + s1
    corners = torch.stack([o, c1, c1 + s2, o + s2], -2)  # (N, P, 4, 3)
    edges = _cross(corners, corners.roll(-1, -2))  # planes through the centre and an edge
    centre = o + 0.5 * (s1 + s2)
    edges = edges * _dot(edges, centre[..., None, :]).sign()[..., None]  # interior on the + side
    nrm = _cross(e1, e2)
    d = _dot(nrm, o)  # plane nrm . X = d
    valid = (planes[..., 19] > 0) & (d.abs() > 1e-9)
    inv_depth = nrm / torch.where(valid, d, 1.0)[..., None]  # 1/z = (nrm / d) . ray  for ray = K^-1 (u, v, 1)
    q1 = e1 - _dot(e1, o)[..., None] * inv_depth  # plane coordinate s times 1/z
    q2 = e2 - _dot(e2, o)[..., None] * inv_depth
    tm = planes[..., 11:17, None]  # (N, P, 6, 1)
    tex_num = tm[..., 0::3, :] * q1[..., None, :] + tm[..., 1::3, :] * q2[..., None, :] + tm[..., 2::3, :] * inv_depth[..., None, :]
    a, b, cc = torch.cat([edges, inv_depth[..., None, :], tex_num], -2).unbind(-1)  # (N, P, 7) on rays
    coef = torch.stack([a * kinv[0], b * kinv[2], a * kinv[1] + b * kinv[3] + cc], -1)  # on pixels
    return torch.where(valid[..., None, None], coef, 0.0), planes[..., 17:19], valid


def _fundamental(R: torch.Tensor, t: torch.Tensor, K_inv: torch.Tensor) -> torch.Tensor:
    """F = K^-T [t]x R K^-1 with unit Frobenius norm, largest-|.| entry positive ('fbn').  (B, 3, 3)."""
    t0, t1, t2 = t.unbind(-1)
    zero = torch.zeros_like(t0)
    tx = torch.stack([zero, -t2, t1, t2, zero, -t0, -t1, t0, zero], -1).reshape(-1, 3, 3)
    F = _mm(_mm(K_inv.T, _mm(tx, R)), K_inv)
    flat = F.reshape(-1, 9)
    sq = flat * flat
    sq = sq[:, 0:3] + sq[:, 3:6] + sq[:, 6:9]
    fro = (sq[:, 0] + sq[:, 1] + sq[:, 2]).sqrt()
    pivot = flat.gather(1, flat.abs().argmax(1, keepdim=True))
    return F * (pivot.sign() / fro[:, None])[..., None]


@functools.lru_cache(maxsize=4)
def texture_bank(device: str = "cpu") -> torch.Tensor:
    """The shared surface texture: 1/f noise plus random blocks, zero mean, unit std.  -> (1, 1, T, T).

    Generated once per process (on the CPU, from a fixed seed, then moved to ``device``); planes
    sample it with reflection padding, so it tiles without seams.
    """
    n = TEXTURE_SIZE
    g = torch.Generator().manual_seed(20180312)
    fy, fx = torch.fft.fftfreq(n, dtype=torch.float64)[:, None], torch.fft.rfftfreq(n, dtype=torch.float64)[None]
    amp = (fx**2 + fy**2).clamp_min(1.0 / n**2) ** -0.35  # amplitude ~ f^-0.7: detail at all scales
    noise = torch.fft.irfft2(torch.fft.rfft2(torch.randn(n, n, generator=g, dtype=torch.float64)) * amp, s=(n, n))
    blocks = torch.zeros(n, n, dtype=torch.float64)
    for x0, y0, lw, lh, v in torch.rand(1500, 5, generator=g, dtype=torch.float64).tolist():
        w, h = int(3 * 20 ** lw), int(3 * 20 ** lh)  # 3 .. 60 texels
        x0, y0 = int(x0 * (n - w)), int(y0 * (n - h))
        blocks[y0 : y0 + h, x0 : x0 + w] += 2.0 * v - 1.0
    bank = noise / noise.std() + 0.8 * blocks / blocks.std()
    bank = ((bank - bank.mean()) / bank.std()).clamp(-3.0, 3.0)
    return bank.float().to(device)[None, None].contiguous()


@functools.lru_cache(maxsize=4)
def noise_bank(device: str = "cpu") -> torch.Tensor:
    """2**NOISE_BANK_BITS standard normal float32 values (fixed seed, made on the CPU).  -> (2**bits,).

    View k reads pixel p's noise at index (a_k p + b_k) mod 2**bits, a_k odd: a per-view
    permutation of the bank, so the noise of any two views (a and b of a pair too) is unrelated
    (it repeats within a view only in images of more than 2**bits pixels).
    """
    g = torch.Generator().manual_seed(0x0DDBA11)
    return torch.randn(1 << NOISE_BANK_BITS, generator=g).to(device)


def _row_intervals(
    alpha: torch.Tensor, delta: torch.Tensor, valid: torch.Tensor, width: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per row, the pixels u (integers) where a ray is inside all 4 edges of a rectangle.

    alpha (N, 1, P, 4), delta (N, H, P, 4): edge k holds where alpha u + delta >= 0.  valid (N, P).
    Returns kl, kh (N, H, P) int16: the pixels kl <= u < kh, in [0, width]; empty: kl = width, kh = 0.
    """
    cut = -delta / alpha  # inf / nan where alpha == 0: masked below
    lo = torch.where(alpha > 0, cut, -math.inf).amax(-1).clamp_(-1, width)
    hi = torch.where(alpha < 0, cut, math.inf).amin(-1).clamp_(-1, width)
    empty = ((alpha == 0) & (delta < 0)).any(-1) | (lo >= hi) | ~valid[:, None]
    lo, hi = lo.masked_fill_(empty, float(width)), hi.masked_fill_(empty, -1.0)
    return lo.ceil_().clamp_(0, width).to(torch.int16), hi.ceil_().clamp_(0, width).to(torch.int16)


def _pieces(
    kl: torch.Tensor, kh: torch.Tensor, a_w: torch.Tensor, d_w: torch.Tensor, width: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Cut each row where any plane starts or ends and find the nearest plane on each piece.

    kl, kh (N, H, P) int16 pixel ranges [kl, kh); a_w (N, 1, P), d_w (N, H, P): 1/z = a_w u + d_w.
    Returns the sorted piece starts (N, H, S + 1) int16 (pixels start <= u < next start) and the
    nearest plane of each piece (N, H, S), P where no plane is hit; S = 2 P + 1.  Which planes
    cover a pixel is constant on a piece, and planes never cross, so the nearest one is too: it is
    found at the piece's first pixel (float32: planes differ there by far more than its rounding).
    """
    N, H, P = kl.shape
    edge = kl.new_zeros((N, H, 1))
    starts = torch.cat([kl, kh, edge, edge + width], -1).sort(-1).values
    u = starts[..., :-1, None]  # (N, H, S, 1) first pixel of each piece
    inv_z = (a_w.float()[:, :, None] * u).add_(d_w.float()[:, :, None])  # (N, H, S, P)
    inv_z.masked_fill_((u < kl[:, :, None]) | (u >= kh[:, :, None]), -math.inf)
    best, idx = inv_z.max(-1)
    return starts, idx.masked_fill_(best == -math.inf, P)


def _piece_table(
    alpha: torch.Tensor, delta: torch.Tensor, shade: torch.Tensor, sky: torch.Tensor, idx: torch.Tensor
) -> torch.Tensor:
    """What the pixels of each piece need, as affine functions of u: (8, N H S) float32.

    Rows: tex x (slope, offset), tex y (slope, offset), 1/z (slope, offset), gain, brightness.
    The sky piece has 1/z = -1 (negative marks "nothing hit"), gain 0 and the sky brightness.
    alpha (N, 1, P, 7), delta (N, H, P, 7), shade (N, P, 2), sky (N,), idx (N, H, S).
    """
    N, H, P = delta.shape[:3]
    parts = []
    for k in (5, 6, 4):
        parts += [alpha[..., k].expand(N, H, P), delta[..., k]]
    parts += [shade[:, None, :, 0].expand(N, H, P), shade[:, None, :, 1].expand(N, H, P)]
    sky_part = delta.new_zeros(8, N, H, 1)
    sky_part[5], sky_part[7] = -1.0, sky[:, None, None]
    table = torch.cat([torch.stack(parts), sky_part], -1).float()  # (8, N, H, P + 1)
    return table.gather(-1, idx.expand(8, -1, -1, -1)).reshape(8, -1)


def _shade(table: torch.Tensor, starts: torch.Tensor, img: torch.Tensor, inv_z: torch.Tensor, chunk_rows: int) -> None:
    """Fill img and inv_z (N H, W) float32: texture lookups of the nearest plane of every pixel.

    Pixel u of a row lies in the piece with start <= u < next start (starts (N, H, S + 1), sorted).
    Works on chunks of rows with reused buffers (fresh CPU allocations page-fault, which costs
    more than the maths).
    """
    W, S = img.shape[1], starts.shape[-1] - 1
    starts = starts.long()
    counts = (starts[..., 1:] - starts[..., :-1]).reshape(-1)  # (N H S,), W per row
    first = torch.cumsum(counts, 0) - counts  # first pixel of each piece
    filled = counts > 0
    u = torch.arange(W, dtype=torch.float32, device=img.device)
    bank = texture_bank(str(img.device))
    rows = img.shape[0]
    chunk_rows = min(chunk_rows, rows)
    cols_buf = img.new_empty(8 * chunk_rows * W)
    mark_buf = torch.empty(chunk_rows * W, dtype=torch.int32, device=img.device)
    grid_buf = img.new_empty(2, chunk_rows, W)  # x, y planes: contiguous writes; grid_sample takes the permuted view
    for r0 in range(0, rows, chunk_rows):
        r1 = min(rows, r0 + chunk_rows)
        n = (r1 - r0) * W
        k = torch.nonzero(filled[r0 * S : r1 * S]).squeeze(1) + r0 * S  # pieces with pixels here
        mark = mark_buf[:n].zero_()
        mark[first[k] - r0 * W] = torch.diff(k, prepend=k.new_zeros(1)).int()  # piece index steps
        piece = torch.cumsum(mark, 0, dtype=torch.int32)
        cols = torch.index_select(table, 1, piece, out=cols_buf[: 8 * n].view(8, n)).view(8, r1 - r0, W)
        z = torch.mul(cols[4], u, out=inv_z[r0:r1]).add_(cols[5])
        grid = grid_buf[:, : r1 - r0]
        torch.mul(cols[0], u, out=grid[0]).add_(cols[1]).div_(z)
        torch.mul(cols[2], u, out=grid[1]).add_(cols[3]).div_(z)
        tex = tnf.grid_sample(bank, grid.permute(1, 2, 0)[None], mode="bilinear", padding_mode="reflection", align_corners=False)
        torch.mul(tex[0, 0], cols[6], out=img[r0:r1]).add_(cols[7])


def _shade_all(table: torch.Tensor, starts: torch.Tensor, img: torch.Tensor, inv_z: torch.Tensor, c: _Consts) -> None:
    """_shade without host synchronisation (GPU): every pixel finds its piece by binary search.

    table (8, N H S), starts (N, H, S + 1), img and inv_z (N H, W) filled in place.
    """
    rows, W = img.shape
    S = starts.shape[-1] - 1
    starts = starts.to(torch.int32).reshape(rows, S + 1)
    chunk = max(1, min(rows, GPU_CHUNK_PIXELS // W))
    u_rows = c.u_int.expand(chunk, W).contiguous()
    first = torch.arange(0, chunk * S, S, dtype=torch.int32, device=img.device)[:, None] - 1
    grid = img.new_empty(2, chunk, W)
    for r0 in range(0, rows, chunk):
        r1 = min(rows, r0 + chunk)
        n = r1 - r0
        piece = torch.searchsorted(starts[r0:r1], u_rows[:n], right=True, out_int32=True)  # 1 + piece in row
        piece += first[:n] + r0 * S
        cols = table.index_select(1, piece.view(-1)).view(8, n, W)
        z = torch.mul(cols[4], c.u, out=inv_z[r0:r1]).add_(cols[5])
        gr = grid[:, :n]
        torch.mul(cols[0], c.u, out=gr[0]).add_(cols[1]).div_(z)
        torch.mul(cols[2], c.u, out=gr[1]).add_(cols[3]).div_(z)
        tex = tnf.grid_sample(c.bank, gr.permute(1, 2, 0)[None], mode="bilinear", padding_mode="reflection", align_corners=False)
        torch.mul(tex[0, 0], cols[6], out=img[r0:r1]).add_(cols[7])


def _render(
    coef: torch.Tensor,
    shade: torch.Tensor,
    valid: torch.Tensor,
    sky: torch.Tensor,
    height: int,
    width: int,
    c: _Consts,
    step: int | None = None,
    chunk_rows: int | None = None,
    sync_free: bool | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Ray-cast N views of piecewise-planar scenes whose rectangles never cross.

    coef (N, P, 7, 3) float64 (see _plane_coefficients), shade (N, P, 2), valid (N, P), sky (N,).
    Returns the intensity (N, 1, H, W) float32 (not clamped) and 1/depth (N, 1, H, W) float32,
    negative where no plane is hit.  On the CPU views are done ``step`` at a time (default 1),
    pixels ``chunk_rows`` rows at a time (default CHUNK_PIXELS: cache-sized work), and only the
    planes some row sees take part (a host sync, cheap there).  On a GPU (or with ``sync_free``)
    all views at once with all planes, without host synchronisation: the same pixels.
    """
    N, H, W, dev = coef.shape[0], height, width, coef.device
    img = torch.empty(N * H, W, dtype=torch.float32, device=dev)
    inv_z = torch.empty_like(img)
    if sync_free is None:
        sync_free = dev.type != "cpu"
    if sync_free:
        alpha, delta = coef[:, None, :, :, 0], c.rows * coef[:, None, :, :, 1] + coef[:, None, :, :, 2]  # (N, 1|H, P, 7)
        kl, kh = _row_intervals(alpha[..., :4], delta[..., :4], valid, W)
        starts, idx = _pieces(kl, kh, alpha[..., 4], delta[..., 4], W)
        _shade_all(_piece_table(alpha, delta, shade, sky, idx), starts, img, inv_z, c)
        return img.view(N, 1, H, W), inv_z.view(N, 1, H, W)
    step = step or 1
    chunk_rows = chunk_rows or max(1, CHUNK_PIXELS // W)
    v = c.rows
    for i in range(0, N, step):
        cf = coef[i : i + step]
        alpha, delta = cf[:, None, :, :, 0], v * cf[:, None, :, :, 1] + cf[:, None, :, :, 2]  # (n, 1|H, P, 7)
        kl, kh = _row_intervals(alpha[..., :4], delta[..., :4], valid[i : i + step], W)
        seen = torch.nonzero((kl < kh).flatten(0, 1).any(0)).squeeze(1)  # planes in view: fewer pieces
        starts, idx = _pieces(kl[..., seen], kh[..., seen], alpha[..., seen, 4], delta[..., seen, 4], W)
        idx = torch.cat([seen, seen.new_full((1,), cf.shape[1])])[idx]  # back to plane numbers, P = sky
        table = _piece_table(alpha, delta, shade[i : i + step], sky[i : i + step], idx)
        rows = slice(i * H, min(N, i + step) * H)
        _shade(table, starts, img[rows], inv_z[rows], chunk_rows)
    return img.view(N, 1, H, W), inv_z.view(N, 1, H, W)


def _blur(img: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur with reflected borders, as shifted sums (exact per sample).  (N, 1, H, W)."""
    r = max(1, math.ceil(3.0 * sigma))
    k = [math.exp(-0.5 * (i / sigma) ** 2) for i in range(-r, r + 1)]
    k = [x / sum(k) for x in k]
    H, W = img.shape[-2:]
    out, tmp = torch.zeros_like(img), torch.empty_like(img)
    x = tnf.pad(img, (r, r, 0, 0), mode="reflect")
    for i, ki in enumerate(k):
        out.add_(torch.mul(x[..., i : i + W], ki, out=tmp))
    x = tnf.pad(out, (0, 0, r, r), mode="reflect")
    out.zero_()
    for i, ki in enumerate(k):
        out.add_(torch.mul(x[..., i : i + H, :], ki, out=tmp))
    return out


# --------------------------------------------------------------------------------------- public


def _seed_list(seeds: Sequence[int] | torch.Tensor) -> list[int]:
    seeds = seeds.tolist() if isinstance(seeds, torch.Tensor) else list(seeds)
    ok = (isinstance(s, numbers.Integral) and not isinstance(s, bool) and 0 <= s < 2**63 for s in seeds)
    if not seeds or not all(ok):
        raise FvizError(f"seeds: must be a non-empty sequence of integers in [0, 2**63) (got {seeds!r})")
    return [int(s) for s in seeds]


def _seed_tensor(seeds: Sequence[int] | torch.Tensor, device: torch.device) -> torch.Tensor:
    """Seeds as int64 (B,) on ``device``, without a blocking copy.

    Seeds already on a GPU are taken as they are (checking their values would need a host sync).
    """
    if isinstance(seeds, torch.Tensor) and seeds.device.type != "cpu":
        if seeds.dim() != 1 or not seeds.numel() or seeds.dtype.is_floating_point or seeds.dtype.is_complex or seeds.dtype == torch.bool:
            raise FvizError(f"seeds: must be a non-empty 1-D integer tensor (got {seeds.dtype} {tuple(seeds.shape)})")
        return seeds.to(device, torch.int64, non_blocking=True)
    t = torch.tensor(_seed_list(seeds), dtype=torch.int64)
    if device.type == "cuda":
        return t.pin_memory().to(device, non_blocking=True)
    return t.to(device)


def _add_noise(img: torch.Tensor, a: torch.Tensor, b: torch.Tensor, bank: torch.Tensor, pix: torch.Tensor) -> torch.Tensor:
    """img (N, 1, H, W) += bank[(a p + b) mod len(bank)] for pixel p (pix: 0 .. H W - 1, int32) of view n, in place."""
    N, _, H, W = img.shape
    idx = pix * a[:, None]  # int32 wraps: mod 2**32
    idx = idx.add_(b[:, None]).bitwise_and_(bank.shape[0] - 1)
    return img.add_(bank.index_select(0, idx.view(-1)).view(N, 1, H, W))


@torch.no_grad()
def _generate(seeds: torch.Tensor, cfg: SceneConfig, c: _Consts, with_depth: bool, internals: bool = False) -> dict:
    """render_batch on tensors: seeds (B,) int64 on the device of ``c``; no host sync on a GPU."""
    with torch.autocast(seeds.device.type, enabled=False):  # float64 geometry, float32 pixels, whatever the caller's
        return _generate_fp(seeds, cfg, c, with_depth, internals)


def _generate_fp(seeds: torch.Tensor, cfg: SceneConfig, c: _Consts, with_depth: bool, internals: bool) -> dict:
    B, H, W = seeds.shape[0], cfg.height, cfg.width
    sc = _sample(seeds, cfg, c)
    coef, shade, valid = _plane_coefficients(sc["planes"], sc["R_cw"], sc["C"], c.kinv)
    img, inv_z = _render(coef, shade, valid, sc["sky"], H, W, c)
    if cfg.exposure > 0:
        img = img * sc["gain"].to(img.dtype)[:, None, None, None]
    if cfg.blur_sigma > 0:
        img = _blur(img, cfg.blur_sigma)
    if cfg.noise_sigma > 0:  # per view from its own index into the bank: the same noise in any batch
        img = _add_noise(img, sc["noise_mul"], sc["noise_add"], c.noise, c.pix)
    img.clamp_(0.0, 1.0).mul_(255.0).round_().div_(255.0)  # exactly the uint8 levels
    K = c.K.expand(B, 3, 3)
    out = {"image_a": img[:B], "image_b": img[B:], "F": _fundamental(sc["R"], sc["t"], c.K_inv)}
    out |= {"K_a": K.clone(), "K_b": K.clone(), "R": sc["R"].contiguous(), "t": sc["t"]}
    if with_depth:
        depth = torch.where(inv_z > 0, 1.0 / inv_z, math.inf)
        out |= {"depth_a": depth[:B], "depth_b": depth[B:]}
    if internals:
        out |= {"coef": coef, "valid": valid}
    return out


class _Graph:
    """render_batch for one (config, device, stream, batch size, with_depth) as a replayed CUDA graph."""

    def __init__(self, cfg: SceneConfig, device: torch.device, batch: int, with_depth: bool) -> None:
        c = _consts(cfg, device)
        self.seeds = torch.zeros(batch, dtype=torch.int64, device=device)
        side = torch.cuda.Stream(device)
        side.wait_stream(torch.cuda.current_stream(device))
        with torch.cuda.stream(side):  # warm up outside the capture (allocator, lazy inits)
            for _ in range(2):
                _generate(self.seeds, cfg, c, with_depth)
        torch.cuda.current_stream(device).wait_stream(side)
        self.graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(self.graph):
            self.out = _generate(self.seeds, cfg, c, with_depth)

    def __call__(self, seeds: torch.Tensor) -> dict[str, torch.Tensor]:
        self.seeds.copy_(seeds)
        self.graph.replay()
        return {k: v.clone() for k, v in self.out.items()}  # the graph's buffers are reused next time


_GRAPHS: OrderedDict = OrderedDict()
_GRAPH_LOCK = threading.Lock()
_GRAPH_FAILED: set = set()


def _render_here(seeds: torch.Tensor, cfg: SceneConfig, device: torch.device, with_depth: bool) -> dict:
    """Render on the current stream: replay (capture the first time) the CUDA graph of this shape."""
    if CUDA_GRAPHS:
        key = (cfg, device, torch.cuda.current_stream(device).stream_id, seeds.shape[0], with_depth)
        with _GRAPH_LOCK:
            graph = _GRAPHS.get(key)
            if graph is None and key not in _GRAPH_FAILED:
                try:
                    graph = _Graph(cfg, device, seeds.shape[0], with_depth)
                except Exception as exc:  # noqa: BLE001 - any capture failure: run eagerly instead
                    _GRAPH_FAILED.add(key)
                    warnings.warn(f"fviz.data.synthetic: CUDA graph capture failed, rendering eagerly ({exc})", stacklevel=4)
                else:
                    _GRAPHS[key] = graph
                    while len(_GRAPHS) > MAX_GRAPHS:
                        _GRAPHS.popitem(last=False)
            if graph is not None:
                _GRAPHS.move_to_end(key)
                return graph(seeds)
    return _generate(seeds, cfg, _consts(cfg, device), with_depth)


_SIDE_STREAMS: dict = {}


def _render_cuda(seeds: Sequence[int] | torch.Tensor, cfg: SceneConfig, device: torch.device, with_depth: bool) -> dict:
    """Render on a side stream of our own, which need not wait for the work the caller has queued
    (a training step, say), so the GPU can run both at once; the caller's stream then waits for
    the render, so its later work sees the results.  Seeds given as a list need no wait at all."""
    if not SIDE_STREAM:
        return _render_here(_seed_tensor(seeds, device), cfg, device, with_depth)
    caller = torch.cuda.current_stream(device)
    with _GRAPH_LOCK:
        side = _SIDE_STREAMS.get(device) or _SIDE_STREAMS.setdefault(device, torch.cuda.Stream(device))
    if isinstance(seeds, torch.Tensor) and seeds.device.type != "cpu":
        side.wait_stream(caller)  # the seeds may still be being written there
    with torch.cuda.stream(side):
        out = _render_here(_seed_tensor(seeds, device), cfg, device, with_depth)
    caller.wait_stream(side)
    for v in out.values():
        v.record_stream(caller)  # made on the side stream, used on the caller's: no early reuse of the memory
    return out


def render_batch(
    seeds: Sequence[int] | torch.Tensor,
    config: SceneConfig | None = None,
    device: str | torch.device = "cpu",
    with_depth: bool = False,
) -> dict[str, torch.Tensor]:
    """Render a batch of synthetic pairs, one per seed, on ``device``.

    Returns image_a, image_b (B, 1, H, W) float32 in [0, 1] (uint8 levels / 255), F (B, 3, 3)
    float64 (unit Frobenius norm, 'fbn' sign), K_a, K_b (B, 3, 3), R (B, 3, 3), t (B, 3) float64;
    with ``with_depth`` also depth_a, depth_b (B, 1, H, W) float32 (z in metres, inf for sky).
    The images of seed s are pixel-identical to ``synthetic_pair(s, config)``'s (on the CPU).
    On a CUDA device the call only queues work (no host sync): seeds given as a list are sent
    through pinned memory, seeds already on the GPU are used as they are (values unchecked).
    """
    cfg = _canonical(config or SceneConfig())
    device = torch.device(device)
    if device.type == "cuda" and device.index is None:
        device = torch.device("cuda", torch.cuda.current_device())
    if device.type == "cuda":
        with torch.cuda.device(device):
            return _render_cuda(seeds, cfg, device, with_depth)
    return _generate(_seed_tensor(seeds, device), cfg, _consts(cfg, device), with_depth)


def _cast(coef: np.ndarray, valid: np.ndarray, pix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit of the rays through pixels ``pix`` (M, 2) against all planes (P, 7, 3), float64.

    Returns 1/depth (M,) (0 where nothing is hit) and the plane index (M,) (-1 where nothing is hit).
    """
    vals = np.einsum("pkj,mj->mpk", coef, np.concatenate([pix, np.ones((len(pix), 1))], 1))  # (M, P, 7)
    inside = (vals[..., :4] >= 0).all(-1) & valid & (vals[..., 4] > 0)
    score = np.where(inside, vals[..., 4], -np.inf)
    best = score.max(-1)
    hit = np.isfinite(best)
    return np.where(hit, best, 0.0), np.where(hit, score.argmax(-1), -1)




def _view_planes(seed: int, cfg: SceneConfig) -> tuple[np.ndarray, np.ndarray]:
    """coef (2, P, 7, 3) and valid (2, P) of views a and b of one scene (numpy, for _cast)."""
    c = _consts(_canonical(cfg), torch.device("cpu"))
    with torch.no_grad():
        sc = _sample(torch.tensor([seed], dtype=torch.int64), cfg, c)
        coef, _, valid = _plane_coefficients(sc["planes"], sc["R_cw"], sc["C"], c.kinv)
    return coef.numpy(), valid.numpy()


def _correspondences(
    seed: int, cfg: SceneConfig, coef: np.ndarray, valid: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray
) -> dict[str, np.ndarray]:
    """Exact correspondences: pixels of a, their 3D points, kept where visible in b.

    coef (2, P, 7, 3), valid (2, P): the planes of views a and b.  Returns points_a, points_b
    (M, 2) float64 and the occluded ones (inside b but hidden there).
    """
    W, H = cfg.width, cfg.height
    gen = torch.Generator().manual_seed(seed ^ POINTS_SEED_SALT)
    pix = (torch.rand(cfg.n_points, 2, generator=gen, dtype=torch.float64) * torch.tensor([W - 1.0, H - 1.0])).numpy()
    K_inv = np.linalg.inv(K)
    w_a, _ = _cast(coef[0], valid[0], pix)
    hit = w_a > 0
    X_a = (np.concatenate([pix[hit], np.ones((hit.sum(), 1))], 1) @ K_inv.T) / w_a[hit, None]
    X_b = X_a @ R.T + t
    x_b = X_b @ K.T
    in_front = x_b[:, 2] > 0
    x_b = x_b[:, :2] / np.where(in_front, x_b[:, 2], 1.0)[:, None]
    inside = in_front & (x_b[:, 0] >= -0.5) & (x_b[:, 0] < W - 0.5) & (x_b[:, 1] >= -0.5) & (x_b[:, 1] < H - 0.5)
    w_b, _ = _cast(coef[1], valid[1], x_b[inside])
    z_b = X_b[inside, 2]
    visible = np.abs(w_b * z_b - 1.0) <= VISIBLE_RTOL  # the ray of b hits this very point first
    pa, pb = pix[hit][inside], x_b[inside]
    return {
        "points_a": pa[visible],
        "points_b": pb[visible],
        "occluded_a": pa[~visible],
        "occluded_b": pb[~visible],
        "n_sampled": len(pix),
        "n_hit": int(hit.sum()),
        "n_inside_b": int(inside.sum()),
    }


def synthetic_pair(seed: int, config: SceneConfig | None = None) -> Pair:
    """One synthetic pair with exact ground truth, on the CPU.

    Images are uint8 (H, W); points_a/points_b the exact correspondences (M, 2) float64 of
    ``config.n_points`` random pixels of a that are visible in b.  ``extra`` holds depth_a,
    depth_b (H, W) float32 (inf for sky), the occluded samples (occluded_a, occluded_b: inside b
    but hidden there), the sample counts and the config.
    """
    cfg = _canonical(config or SceneConfig())
    seed = _seed_list([seed])[0]
    out = _generate(torch.tensor([seed], dtype=torch.int64), cfg, _consts(cfg, torch.device("cpu")), True, internals=True)
    K, R, t = (out[k][0].numpy() for k in ("K_a", "R", "t"))
    corr = _correspondences(seed, cfg, out["coef"].numpy(), out["valid"].numpy(), K, R, t)
    to_u8 = lambda x: (x[0, 0] * 255.0).round().to(torch.uint8).numpy()
    pid = PairId(
        source="synthetic",
        sequence=str(seed),
        kind="stereo" if cfg.stereo else "temporal",
        frame_a=0,
        frame_b=1,
        cam_a=0,
        cam_b=1 if cfg.stereo else 0,
    )
    extra = {
        "depth_a": out["depth_a"][0, 0].numpy(),
        "depth_b": out["depth_b"][0, 0].numpy(),
        **{k: corr[k] for k in ("occluded_a", "occluded_b", "n_sampled", "n_hit", "n_inside_b")},
        "config": asdict(cfg),
    }
    return Pair(
        id=pid,
        image_a=to_u8(out["image_a"]),
        image_b=to_u8(out["image_b"]),
        K_a=K.copy(),
        K_b=K.copy(),
        R=R.copy(),
        t=t.copy(),
        F_gt=out["F"][0].numpy(),
        gt_accuracy_px=0.0,
        points_a=corr["points_a"],
        points_b=corr["points_b"],
        extra=extra,
    )


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
