"""The synthetic scenes' knobs (:class:`SceneConfig`) and camera (KITTI's, scaled to the image size)."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, replace

import numpy as np

from fviz.errors import FvizError

KITTI_SIZE = (1242, 375)  # (width, height) of KITTI odometry grey images
KITTI_K = (718.856, 718.856, 607.1928, 185.2157)  # fx, fy, cx, cy of KITTI odometry sequence 00


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


def canonical(cfg: SceneConfig) -> SceneConfig:
    """The config with a tuple forward_range (hashable: configs key the caches)."""
    if not isinstance(cfg, SceneConfig):
        raise FvizError(f"config: must be a SceneConfig (got {type(cfg).__name__})")
    return cfg if isinstance(cfg.forward_range, tuple) else replace(cfg, forward_range=tuple(cfg.forward_range))

