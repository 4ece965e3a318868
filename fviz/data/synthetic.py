"""Synthetic KITTI-like image pairs with exact ground truth (F, cameras and correspondences).

Scenes are piecewise planar streets: a road, building facades on both sides (parallel to the
driving direction, a few segments per side joined by short walls), a wall closing the street
far ahead, and axis-aligned boxes and cars (a car is a body box plus a cabin box).  Every plane
is a bounded rectangle carrying a texture fixed to its surface (a shared bank of 1/f noise and
random blocks, placed with a random scale, rotation and offset per plane).

Frames: the *street* frame has x right, y down (the road is the plane y = h), z along the street,
and its origin at the centre of camera a.  Camera frames are OpenCV's (x right, y down, z forward);
a camera maps street points by X_cam = R_cw (X_street - C).  The motion X_b = R X_a + t goes from
camera a to camera b and F (x_b^T F x_a = 0, pixels, OpenCV origin) comes from
:func:`fviz.geometry.fundamental_from_motion`.

Rendering is exact ray casting against all planes, vectorised in torch.  For a plane, 1/depth and
the four "ray inside edge k" tests are affine functions of the pixel (u, v), so along one image row
each plane covers one interval of u.  Because the rectangles of a scene never cross (they may only
touch along edges), the nearest plane along a row can only change at an interval end: the renderer
sorts the interval ends of a row, finds the nearest plane at the middle of each piece (rows x pieces
x planes, cheap) and spreads the winner over the pixels of the piece.  Correspondences use the
direct form (rays x planes, nearest positive hit inside the rectangle) in float64.

Everything is deterministic per seed: scene parameters come from a seeded ``torch.Generator`` on
the CPU, and the per-pixel work uses only elementwise operations, so a sample renders to the same
pixels alone or inside any batch.
"""

from __future__ import annotations

import functools
import math
import numbers
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn.functional as tnf

from fviz.data.pair import Pair, PairId
from fviz.errors import FvizError
from fviz.geometry import fundamental_from_motion, normalize

KITTI_SIZE = (1242, 375)  # (width, height) of KITTI odometry grey images
KITTI_K = (718.856, 718.856, 607.1928, 185.2157)  # fx, fy, cx, cy of KITTI odometry sequence 00
TEXTURE_SIZE = 1024  # texels per side of the shared texture bank
NOISE_SEED_SALT = 0x5EED_F00D  # noise generator seed = seed ^ salt (independent of the scene stream)
POINTS_SEED_SALT = 0xC0FF_EE11  # the same for the pixels sampled for correspondences
VISIBLE_RTOL = 1e-6  # relative depth tolerance of the visibility test in image b
CHUNK_PIXELS = 1 << 17  # pixels shaded per step on the CPU (keeps the work buffers in cache)

# Materials: (texel size in metres, texture gain, brightness range).
_ROAD = (0.025, 0.10, (0.25, 0.45))
_FACADE = (0.03, 0.16, (0.35, 0.75))
_BOX = (0.015, 0.18, (0.20, 0.80))


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
        integer("n_points", 1, 10_000_000)


def intrinsics(width: int = KITTI_SIZE[0], height: int = KITTI_SIZE[1]) -> np.ndarray:
    """KITTI's K scaled to an image of ``width`` x ``height`` (pixel centres at integers).  -> (3, 3)."""
    fx, fy, cx, cy = KITTI_K
    sx, sy = width / KITTI_SIZE[0], height / KITTI_SIZE[1]
    return np.array([[fx * sx, 0.0, (cx + 0.5) * sx - 0.5], [0.0, fy * sy, (cy + 0.5) * sy - 0.5], [0.0, 0.0, 1.0]])


# ------------------------------------------------------------------------------- scene sampling


class _Uniform:
    """Uniform draws from a seeded torch.Generator, served as python floats (cheap in python code)."""

    def __init__(self, seed: int) -> None:
        self.gen = torch.Generator().manual_seed(seed)
        self.buf: list[float] = []

    def __call__(self, lo: float = 0.0, hi: float = 1.0) -> float:
        if not self.buf:
            self.buf = torch.rand(256, generator=self.gen, dtype=torch.float64).tolist()[::-1]
        return lo + (hi - lo) * self.buf.pop()


def _rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Ry(yaw) @ Rx(pitch) @ Rz(roll), angles in radians (y down: positive yaw turns right).  -> (3, 3)."""
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return ry @ rx @ rz


@dataclass
class _Rect:
    """A textured rectangle of the street frame: corners origin + [0, size0] e1 + [0, size1] e2."""

    origin: tuple[float, float, float]
    e1: tuple[float, float, float]
    e2: tuple[float, float, float]
    size: tuple[float, float]
    tex: np.ndarray  # (2, 3): plane coordinates (s, r, 1) in metres -> grid_sample coordinates
    shade: tuple[float, float]  # (gain, brightness): intensity = gain * texture + brightness
    valid: bool = True


_X, _Y, _Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)


def _rect(rnd: _Uniform, cfg: SceneConfig, material, origin, e1, e2, size, valid=True) -> _Rect:
    """A rectangle with a random placement of the texture bank (scale, rotation, offset) and shade."""
    texel, gain, (b_lo, b_hi) = material
    scale = 2.0 / (TEXTURE_SIZE * texel / cfg.texture_frequency * rnd(0.7, 1.4))  # metres -> [-1, 1] units
    a = rnd(0.0, 2.0 * math.pi)
    c, s = scale * math.cos(a), scale * math.sin(a)
    tex = np.array([[c, -s, rnd(-1.0, 1.0)], [s, c, rnd(-1.0, 1.0)]])
    shade = (gain * cfg.texture_contrast * rnd(0.75, 1.25), rnd(b_lo, b_hi))
    return _Rect(origin, e1, e2, size, tex, shade, valid and size[0] > 1e-3 and size[1] > 1e-3)


@dataclass
class _Box:
    """An axis-aligned box standing on the road: its 5 visible-side faces (no bottom)."""

    lo: np.ndarray  # (3,) min corner (x0, y_top, z0)
    hi: np.ndarray  # (3,) max corner (x1, y_road, z1)
    faces: dict[str, _Rect]

    def facing(self, centre: np.ndarray) -> list[_Rect]:
        """The 3 faces towards a camera centre (x side, z side, top); back faces never win anyway."""
        x = "x1" if centre[0] > self.hi[0] else "x0"
        z = "z1" if centre[2] > self.hi[2] else "z0"
        return [self.faces[x], self.faces[z], self.faces["top"]]


def _box(rnd: _Uniform, cfg: SceneConfig, lo, hi, valid: bool) -> _Box:
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    w, h, l = x1 - x0, y1 - y0, z1 - z0
    faces = {
        "x0": _rect(rnd, cfg, _BOX, (x0, y0, z0), _Z, _Y, (l, h), valid),
        "x1": _rect(rnd, cfg, _BOX, (x1, y0, z0), _Z, _Y, (l, h), valid),
        "z0": _rect(rnd, cfg, _BOX, (x0, y0, z0), _X, _Y, (w, h), valid),
        "z1": _rect(rnd, cfg, _BOX, (x0, y0, z1), _X, _Y, (w, h), valid),
        "top": _rect(rnd, cfg, _BOX, (x0, y0, z0), _X, _Z, (w, l), valid),
    }
    return _Box(np.array(lo, float), np.array(hi, float), faces)


@dataclass
class _Scene:
    """One sampled scene: planes (street frame), both cameras and the ground truth."""

    seed: int
    fixed: list[_Rect]  # road, facades, junction walls, end wall
    boxes: list[_Box]  # 2 per object (body, cabin); invalid slots are padding
    sky: float
    K: np.ndarray  # (3, 3), same for both cameras
    R: np.ndarray  # (3, 3) motion a -> b
    t: np.ndarray  # (3,)
    cams: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]  # ((R_cw, C) of a, of b)

    def planes(self, view: int) -> list[_Rect]:
        """The P planes camera ``view`` (0 = a, 1 = b) needs, P fixed for a config."""
        centre = self.cams[view][1]
        return self.fixed + [f for box in self.boxes for f in box.facing(centre)]


def _facades(
    rnd: _Uniform, cfg: SceneConfig, h: float, side: float, z_cuts: list[float]
) -> tuple[list[_Rect], list[float]]:
    """Facade segments of one side (side = -1 left, +1 right) and the junction walls between them.

    Returns the rectangles and the lateral distance of each segment.
    """
    n = len(z_cuts) - 1
    base = rnd(3.0, 7.0)
    dist = [base + rnd(0.0, 2.5) for _ in range(n)]
    tall = [rnd(5.0, 18.0) for _ in range(n)]
    rects = [
        _rect(rnd, cfg, _FACADE, (side * dist[k], h - tall[k], z_cuts[k]), _Z, _Y, (z_cuts[k + 1] - z_cuts[k], tall[k]))
        for k in range(n)
    ]
    for k in range(n - 1):  # the end wall of the building that sticks out further into the street
        near = 0 if dist[k] < dist[k + 1] else 1
        x_in, x_out = side * min(dist[k], dist[k + 1]), side * max(dist[k], dist[k + 1])
        height = tall[k + near]
        origin = (min(x_in, x_out), h - height, z_cuts[k + 1])
        rects.append(_rect(rnd, cfg, _FACADE, origin, _X, _Y, (abs(x_out - x_in), height)))
    return rects, dist


def _objects(rnd: _Uniform, cfg: SceneConfig, h: float, x_range: tuple[float, float], z_min: float) -> list[_Box]:
    """``cfg.n_boxes`` cars (body + cabin) or crates (body + unused cabin slot) that do not overlap."""
    boxes: list[_Box] = []
    placed: list[tuple[float, float, float, float]] = []  # footprints (x0, x1, z0, z1)
    for _ in range(cfg.n_boxes):
        car = rnd() < 0.6
        if car:
            w, l, bh = rnd(1.6, 1.9), rnd(3.6, 4.8), rnd(0.8, 1.1)
        else:
            w, l, bh = rnd(0.5, 2.5), rnd(0.5, 2.5), rnd(0.5, 2.5)
        spot = None
        for _try in range(8):  # rejection sampling of a free spot between the facades
            x0 = rnd(x_range[0] + 0.3, x_range[1] - 0.3 - w)
            z0 = rnd(z_min, z_min + 30.0)
            fits = x_range[0] + 0.3 <= x0 and x0 + w <= x_range[1] - 0.3
            apart = (x0 > b[1] + 0.3 or x0 + w < b[0] - 0.3 or z0 > b[3] + 0.3 or z0 + l < b[2] - 0.3 for b in placed)
            if fits and all(apart):
                spot = (x0, z0)
                break
        ok = spot is not None
        x0, z0 = spot if ok else (0.0, z_min)
        placed += [(x0, x0 + w, z0, z0 + l)] if ok else []
        boxes.append(_box(rnd, cfg, (x0, h - bh, z0), (x0 + w, h, z0 + l), ok))
        # cabin: sits on the body of a car; a crate keeps an invalid cabin slot so P stays fixed
        cw, cl, ch = w - rnd(0.1, 0.2), l * rnd(0.45, 0.55), rnd(0.4, 0.6)
        cx0, cz0 = x0 + (w - cw) / 2, z0 + l * rnd(0.25, 0.35)
        boxes.append(_box(rnd, cfg, (cx0, h - bh - ch, cz0), (cx0 + cw, h - bh, cz0 + cl), ok and car))
    return boxes


def _sample_scene(seed: int, cfg: SceneConfig) -> _Scene:
    """Draw one street scene and camera pair from ``seed`` (numpy float64, street frame)."""
    rnd = _Uniform(seed)
    K = intrinsics(cfg.width, cfg.height)
    h = rnd(1.55, 1.75)  # camera height: the road is the plane y = h
    far = rnd(60.0, 140.0)  # the street ends with a wall at z = far
    n = cfg.facade_segments
    z_cuts = [-6.0] + sorted(rnd(5.0, far - 10.0) for _ in range(n - 1)) + [far]
    left, d_left = _facades(rnd, cfg, h, -1.0, z_cuts)
    right, d_right = _facades(rnd, cfg, h, 1.0, z_cuts)
    road = _rect(rnd, cfg, _ROAD, (-max(d_left), h, z_cuts[0]), _X, _Z, (max(d_left) + max(d_right), far - z_cuts[0]))
    end_h = rnd(6.0, 20.0)
    end = _rect(rnd, cfg, _FACADE, (-d_left[-1], h - end_h, far), _X, _Y, (d_left[-1] + d_right[-1], end_h))
    boxes = _objects(rnd, cfg, h, (-min(d_left), min(d_right)), cfg.forward_range[1] + 2.0)
    sky = rnd(0.75, 0.95)

    d2r = math.pi / 180.0
    R_aw = _rotation(rnd(-2.0, 2.0) * d2r, rnd(-1.0, 1.0) * d2r, rnd(-1.0, 1.0) * d2r)  # camera mount
    if cfg.stereo:
        Q, c_b = np.eye(3), np.array([cfg.baseline, 0.0, 0.0])
    else:  # car-like: drive forward along an arc (translation at half the yaw), small pitch and roll
        fwd = rnd(*cfg.forward_range)
        yaw = rnd(-1.0, 1.0) * cfg.rotation_deg * d2r
        Q = _rotation(yaw, rnd(-0.3, 0.3) * cfg.rotation_deg * d2r, rnd(-0.3, 0.3) * cfg.rotation_deg * d2r)
        c_b = fwd * np.array([math.sin(yaw / 2), rnd(-0.02, 0.02), math.cos(yaw / 2)])
    R, t = Q.T, -Q.T @ c_b  # X_b = Q^T (X_a - c_b), with Q the axes and c_b the centre of b in frame a
    cams = ((R_aw, np.zeros(3)), (R @ R_aw, R_aw.T @ c_b))
    return _Scene(seed, left + right + [road, end], boxes, sky, K, R, t, cams)


# ------------------------------------------------------------------------ planes -> pixel maps


def _plane_coefficients(
    rects: list[_Rect], R_cw: np.ndarray, C: np.ndarray, K: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-plane affine functions of the pixel for one camera.

    Returns coef (P, 7, 3), shade (P, 2), valid (P,).  Row k of coef is (a, b, c) with value
    a u + b v + c at pixel (u, v): rows 0-3 are >= 0 iff the ray is inside edge k of the rectangle
    (the cone over a convex polygon), row 4 is 1/depth (z), rows 5-6 are the grid_sample texture
    coordinates times 1/depth.
    """
    o = (np.array([r.origin for r in rects]) - C) @ R_cw.T  # (P, 3) in camera coordinates
    e1 = np.array([r.e1 for r in rects]) @ R_cw.T
    e2 = np.array([r.e2 for r in rects]) @ R_cw.T
    size = np.array([r.size for r in rects])
    s1, s2 = e1 * size[:, :1], e2 * size[:, 1:]
    corners = np.stack([o, o + s1, o + s1 + s2, o + s2], 1)  # (P, 4, 3)
    edges = np.cross(corners, np.roll(corners, -1, axis=1))  # planes through the centre and an edge
    centre = o + 0.5 * (s1 + s2)
    edges *= np.sign(np.einsum("pkj,pj->pk", edges, centre))[..., None]  # interior on the + side
    n = np.cross(e1, e2)
    d = np.einsum("pj,pj->p", n, o)  # plane n . X = d
    valid = np.array([r.valid for r in rects]) & (np.abs(d) > 1e-9)
    inv_depth = n / np.where(valid, d, 1.0)[:, None]  # 1/z = (n / d) . ray  for ray = K^-1 (u, v, 1)
    q1 = e1 - np.einsum("pj,pj->p", e1, o)[:, None] * inv_depth  # plane coordinate s times 1/z
    q2 = e2 - np.einsum("pj,pj->p", e2, o)[:, None] * inv_depth
    tex = np.array([r.tex for r in rects])  # (P, 2, 3)
    tex_num = tex[:, :, :1] * q1[:, None] + tex[:, :, 1:2] * q2[:, None] + tex[:, :, 2:] * inv_depth[:, None]
    funcs = np.concatenate([edges, inv_depth[:, None], tex_num], 1)  # (P, 7, 3) on rays
    coef = funcs @ np.linalg.inv(K)  # on pixels: f . K^-1 (u, v, 1)
    coef[~valid] = 0.0
    return coef, np.array([r.shade for r in rects]), valid


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


def _row_intervals(
    alpha: torch.Tensor, delta: torch.Tensor, valid: torch.Tensor, width: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per row, the u-interval where a ray is inside all 4 edges of a rectangle.

    alpha (N, 1, P, 4), delta (N, H, P, 4): edge k holds where alpha u + delta >= 0.  valid (N, P).
    Returns lo, hi (N, H, P) clamped to [-1, width]; empty intervals get lo = width, hi = -1.
    """
    cut = -delta / alpha  # inf / nan where alpha == 0: masked below
    lo = torch.where(alpha > 0, cut, -math.inf).amax(-1).clamp_(-1, width)
    hi = torch.where(alpha < 0, cut, math.inf).amin(-1).clamp_(-1, width)
    empty = ((alpha == 0) & (delta < 0)).any(-1) | (lo >= hi) | ~valid[:, None]
    return lo.masked_fill_(empty, float(width)), hi.masked_fill_(empty, -1.0)


def _pieces(
    lo: torch.Tensor, hi: torch.Tensor, a_w: torch.Tensor, d_w: torch.Tensor, width: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Cut each row at all interval ends and find the nearest plane on each piece.

    lo, hi (N, H, P) interval ends; a_w (N, 1, P), d_w (N, H, P): 1/z = a_w u + d_w.
    Returns the sorted ends (N, H, S + 1) and the nearest plane of each piece (N, H, S), P where
    no plane is hit; S = 2 P + 1.  Planes never cross, so the nearest one is constant on a piece.
    """
    N, H, P = lo.shape
    edge = lo.new_full((N, H, 1), -1.0)
    ends = torch.cat([lo, hi, edge, edge.new_full((N, H, 1), float(width))], -1).sort(-1).values
    mid = ends[..., 1:].add(ends[..., :-1]).mul_(0.5).unsqueeze(-1)  # (N, H, S, 1)
    inv_z = (a_w[:, :, None] * mid).add_(d_w[:, :, None])  # (N, H, S, P)
    inv_z.masked_fill_((mid < lo[:, :, None]) | (mid > hi[:, :, None]), -math.inf)
    best, idx = inv_z.max(-1)
    return ends, idx.masked_fill_(best == -math.inf, P)


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


def _shade(table: torch.Tensor, ends: torch.Tensor, img: torch.Tensor, inv_z: torch.Tensor, chunk_rows: int) -> None:
    """Fill img and inv_z (N H, W) float32: texture lookups of the nearest plane of every pixel.

    Pixel u of a row lies in the piece with ceil(start) <= u < ceil(end).  Works on chunks of
    rows with reused buffers (fresh CPU allocations page-fault, which costs more than the maths).
    """
    W, S = img.shape[1], ends.shape[-1] - 1
    starts = ends.ceil().clamp_(0, W).long()
    counts = (starts[..., 1:] - starts[..., :-1]).reshape(-1)  # (N H S,), W per row
    first = torch.cumsum(counts, 0) - counts  # first pixel of each piece
    filled = counts > 0
    u = torch.arange(W, dtype=torch.float32, device=img.device)
    bank = texture_bank(str(img.device))
    rows = img.shape[0]
    chunk_rows = min(chunk_rows, rows)
    cols_buf = img.new_empty(8 * chunk_rows * W)
    mark_buf = torch.empty(chunk_rows * W, dtype=torch.int32, device=img.device)
    grid_buf = img.new_empty(1, chunk_rows, W, 2)
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
        torch.mul(cols[0], u, out=grid[0, ..., 0]).add_(cols[1]).div_(z)
        torch.mul(cols[2], u, out=grid[0, ..., 1]).add_(cols[3]).div_(z)
        tex = tnf.grid_sample(bank, grid, mode="bilinear", padding_mode="reflection", align_corners=False)
        torch.mul(tex[0, 0], cols[6], out=img[r0:r1]).add_(cols[7])


def _render(
    coef: torch.Tensor,
    shade: torch.Tensor,
    valid: torch.Tensor,
    sky: torch.Tensor,
    height: int,
    width: int,
    step: int | None = None,
    chunk_rows: int | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Ray-cast N views of piecewise-planar scenes whose rectangles never cross.

    coef (N, P, 7, 3) float64 (see _plane_coefficients), shade (N, P, 2), valid (N, P), sky (N,).
    Returns the intensity (N, 1, H, W) float32 (not clamped) and 1/depth (N, 1, H, W) float32,
    negative where no plane is hit.  Views are done ``step`` at a time, pixels ``chunk_rows`` rows
    at a time: by default one view and CHUNK_PIXELS on the CPU (cache-sized work), all at once else.
    """
    N, H, W, dev = coef.shape[0], height, width, coef.device
    img = torch.empty(N * H, W, dtype=torch.float32, device=dev)
    inv_z = torch.empty_like(img)
    cpu = dev.type == "cpu"
    step = step or (1 if cpu else N)
    chunk_rows = chunk_rows or (max(1, CHUNK_PIXELS // W) if cpu else N * H)
    v = torch.arange(H, dtype=torch.float64, device=dev)[:, None, None]
    for i in range(0, N, step):
        c = coef[i : i + step]
        alpha, delta = c[:, None, :, :, 0], v * c[:, None, :, :, 1] + c[:, None, :, :, 2]  # (n, 1|H, P, 7)
        lo, hi = _row_intervals(alpha[..., :4], delta[..., :4], valid[i : i + step], W)
        seen = torch.nonzero((lo < hi).flatten(0, 1).any(0)).squeeze(1)  # planes in view: fewer pieces
        ends, idx = _pieces(lo[..., seen], hi[..., seen], alpha[..., seen, 4], delta[..., seen, 4], W)
        idx = torch.cat([seen, seen.new_full((1,), c.shape[1])])[idx]  # back to plane numbers, P = sky
        table = _piece_table(alpha, delta, shade[i : i + step], sky[i : i + step], idx)
        rows = slice(i * H, min(N, i + step) * H)
        _shade(table, ends, img[rows], inv_z[rows], chunk_rows)
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


def _render_scenes(scenes: list[_Scene], cfg: SceneConfig, device: str | torch.device) -> dict[str, torch.Tensor]:
    """Render views a and b of each scene: images (B, 1, H, W) float32 in [0, 1] and 1/depth maps."""
    B, H, W = len(scenes), cfg.height, cfg.width
    per_view = [_plane_coefficients(s.planes(v), *s.cams[v], s.K) for v in (0, 1) for s in scenes]  # a's, then b's
    coef, shade, valid = (torch.from_numpy(np.stack(x)).to(device) for x in zip(*per_view))
    sky = torch.tensor([s.sky for s in scenes] * 2, dtype=torch.float64, device=device)
    img, inv_z = _render(coef, shade, valid, sky, H, W)
    if cfg.blur_sigma > 0:
        img = _blur(img, cfg.blur_sigma)
    if cfg.noise_sigma > 0:  # per sample, from its own generator: the same noise in any batch
        buf = torch.empty(H, W, device=device)
        for b, s in enumerate(scenes):
            gen = torch.Generator(device=device).manual_seed(s.seed ^ NOISE_SEED_SALT)
            for view in (b, B + b):
                img[view, 0].add_(torch.randn(H, W, generator=gen, out=buf).mul_(cfg.noise_sigma / 255.0))
    img.clamp_(0.0, 1.0).mul_(255.0).round_().div_(255.0)  # exactly the uint8 levels
    return {"image_a": img[:B], "image_b": img[B:], "inv_depth_a": inv_z[:B], "inv_depth_b": inv_z[B:]}


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
    The images of seed s are pixel-identical to ``synthetic_pair(s, config)``'s.
    """
    cfg = config or SceneConfig()
    return _render_batch([_sample_scene(s, cfg) for s in _seed_list(seeds)], cfg, device, with_depth)


def _render_batch(scenes: list[_Scene], cfg: SceneConfig, device: str | torch.device, with_depth: bool) -> dict:
    """render_batch for scenes already sampled."""
    out = _render_scenes(scenes, cfg, device)
    K = np.stack([s.K for s in scenes])
    R = np.stack([s.R for s in scenes])
    t = np.stack([s.t for s in scenes])
    F = normalize(fundamental_from_motion(K, K, R, t), "fbn")
    as_t = functools.partial(torch.as_tensor, dtype=torch.float64, device=device)
    res = {"image_a": out["image_a"], "image_b": out["image_b"], "F": as_t(F)}
    res |= {"K_a": as_t(K), "K_b": as_t(K.copy()), "R": as_t(R), "t": as_t(t)}
    if with_depth:
        for v in "ab":
            inv_z = out[f"inv_depth_{v}"]
            res[f"depth_{v}"] = torch.where(inv_z > 0, 1.0 / inv_z, math.inf)
    return res


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


def _correspondences(scene: _Scene, cfg: SceneConfig) -> dict[str, np.ndarray]:
    """Exact correspondences: pixels of a, their 3D points, kept where visible in b.

    Returns points_a, points_b (M, 2) float64 and the occluded ones (inside b but hidden there).
    """
    W, H = cfg.width, cfg.height
    gen = torch.Generator().manual_seed(scene.seed ^ POINTS_SEED_SALT)
    pix = (torch.rand(cfg.n_points, 2, generator=gen, dtype=torch.float64) * torch.tensor([W - 1.0, H - 1.0])).numpy()
    coef_a, _, valid_a = _plane_coefficients(scene.planes(0), *scene.cams[0], scene.K)
    coef_b, _, valid_b = _plane_coefficients(scene.planes(1), *scene.cams[1], scene.K)
    K_inv = np.linalg.inv(scene.K)
    w_a, _ = _cast(coef_a, valid_a, pix)
    hit = w_a > 0
    X_a = (np.concatenate([pix[hit], np.ones((hit.sum(), 1))], 1) @ K_inv.T) / w_a[hit, None]
    X_b = X_a @ scene.R.T + scene.t
    x_b = X_b @ scene.K.T
    in_front = x_b[:, 2] > 0
    x_b = x_b[:, :2] / np.where(in_front, x_b[:, 2], 1.0)[:, None]
    inside = in_front & (x_b[:, 0] >= -0.5) & (x_b[:, 0] < W - 0.5) & (x_b[:, 1] >= -0.5) & (x_b[:, 1] < H - 0.5)
    w_b, _ = _cast(coef_b, valid_b, x_b[inside])
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
    cfg = config or SceneConfig()
    seed = _seed_list([seed])[0]
    scene = _sample_scene(seed, cfg)
    out = _render_batch([scene], cfg, "cpu", with_depth=True)
    corr = _correspondences(scene, cfg)
    to_u8 = lambda x: (x[0, 0] * 255.0).round().to(torch.uint8).numpy()  # noqa: E731
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
        K_a=scene.K.copy(),
        K_b=scene.K.copy(),
        R=scene.R.copy(),
        t=scene.t.copy(),
        F_gt=out["F"][0].numpy(),
        gt_accuracy_px=0.0,
        points_a=corr["points_a"],
        points_b=corr["points_b"],
        extra=extra,
    )


__all__ = ["KITTI_K", "KITTI_SIZE", "SceneConfig", "intrinsics", "render_batch", "synthetic_pair", "texture_bank"]
