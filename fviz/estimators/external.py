"""Estimators and two-view checks from PoseLib and COLMAP (pycolmap), imported only when used.

Estimators (same contract as :mod:`fviz.estimators.classical`: (pair, x_a, x_b) -> (F, inlier_mask)):

- ``poselib``: PoseLib's LO-RANSAC fundamental matrix (7-point samples, MSAC score, local optimisation, then
  a non-linear refinement of the Sampson error, PoseLib's default bundle options). ``--threshold`` is its ``max_epipolar_error``: the
  **Sampson distance in px**, the same test as OpenCV's USAC / MAGSAC++;
- ``poselib-E``: PoseLib's calibrated relative pose (5-point LO-RANSAC on the pair's K_a, K_b), then
  F = K_b^-T [t]x R K_a^-1. ``--threshold`` is again in **px**: PoseLib divides it by the mean focal length
  and tests the Sampson error of E on the normalized points, i.e. about a Sampson distance in px;
- ``colmap``: COLMAP's LO-RANSAC fundamental matrix (``pycolmap.estimate_fundamental_matrix``, 7-point
  samples, Sampson refinement). ``--threshold`` is its ``RANSACOptions.max_error``: the **Sampson distance in px**
  (COLMAP compares the squared Sampson error with max_error^2).

All three take ``--confidence``, ``--max-iters`` (their minimum iteration count is capped to it) and ``--seed``.
The points are passed as fviz holds them (OpenCV's origin, pixel centres at integers): F comes back in the
same coordinates, and the principal points given to PoseLib / COLMAP are K's, in that origin too.

Two-view checks for triage (:mod:`fviz.diagnose`):

- :func:`two_view_configuration`: COLMAP's label of the matches (``estimate_two_view_geometry`` with the
  pair's cameras): calibrated, uncalibrated, planar, panoramic, planar_or_panoramic, watermark, degenerate;
- :func:`bougnoux_focals`: PoseLib's ``focals_from_fundamental`` (Bougnoux's closed form) for F and the
  principal points: NaN where the focal is imaginary (f^2 < 0).
"""

from __future__ import annotations

import numpy as np

from fviz.estimators.classical import RobustConfig

MIN_MATCHES = {"poselib": 7, "poselib-E": 5, "colmap": 8}
MIN_TRIALS = 1000  # PoseLib's and COLMAP's default minimum iterations, capped at --max-iters


def _check(name: str, x_a: np.ndarray) -> None:
    need = MIN_MATCHES[name]
    if len(x_a) < need:
        raise ValueError(f"{name} needs at least {need} matches, got {len(x_a)}")


def _poselib_ransac(cfg: RobustConfig) -> dict:
    return {"max_epipolar_error": cfg.threshold, "success_prob": cfg.confidence, "max_iterations": cfg.max_iters,
            "min_iterations": min(MIN_TRIALS, cfg.max_iters), "seed": cfg.seed}


def poselib_fundamental(pair, x_a: np.ndarray, x_b: np.ndarray, cfg: RobustConfig):
    """PoseLib's ``estimate_fundamental`` (x_b^T F x_a = 0, as fviz)."""
    import poselib

    _check("poselib", x_a)
    F, info = poselib.estimate_fundamental(x_a, x_b, _poselib_ransac(cfg), {})
    return np.asarray(F), np.asarray(info["inliers"], bool)


def pinhole(K: np.ndarray, size: tuple[int, int]) -> dict:
    """PoseLib's / COLMAP's PINHOLE camera of intrinsics K (3, 3) and size (width, height)."""
    return {"model": "PINHOLE", "width": int(size[0]), "height": int(size[1]),
            "params": [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])]}


def poselib_essential(pair, x_a: np.ndarray, x_b: np.ndarray, cfg: RobustConfig):
    """PoseLib's ``estimate_relative_pose`` on the pair's cameras, as F = K_b^-T [t]x R K_a^-1."""
    import poselib

    from fviz.geometry import fundamental_from_motion

    _check("poselib-E", x_a)
    pose, info = poselib.estimate_relative_pose(x_a, x_b, pinhole(pair.K_a, pair.size_a), pinhole(pair.K_b, pair.size_b),
                                                _poselib_ransac(cfg), {})
    F = fundamental_from_motion(pair.K_a, pair.K_b, np.asarray(pose.R), np.asarray(pose.t))
    return F, np.asarray(info["inliers"], bool)


def colmap_fundamental(pair, x_a: np.ndarray, x_b: np.ndarray, cfg: RobustConfig):
    """pycolmap's ``estimate_fundamental_matrix`` (LO-RANSAC); None when COLMAP finds no model."""
    import pycolmap

    _check("colmap", x_a)
    opt = pycolmap.RANSACOptions()
    opt.max_error, opt.confidence, opt.random_seed = cfg.threshold, cfg.confidence, cfg.seed
    opt.max_num_trials, opt.min_num_trials = cfg.max_iters, min(MIN_TRIALS, cfg.max_iters)
    out = pycolmap.estimate_fundamental_matrix(x_a, x_b, opt)
    if out is None:
        return None
    return np.asarray(out["F"]), np.asarray(out["inlier_mask"], bool).reshape(-1)


METHODS = {"poselib": poselib_fundamental, "poselib-E": poselib_essential, "colmap": colmap_fundamental}
NEEDS_K = frozenset({"poselib-E"})  # COLMAP's and PoseLib's F are uncalibrated: they run without K


def external(name: str, cfg: RobustConfig = RobustConfig()):
    """An estimator (pair, x_a, x_b) -> (F, inliers) for one of ``METHODS``' names."""
    method = METHODS[name]

    def estimate(pair, x_a, x_b):
        return method(pair, np.ascontiguousarray(x_a, np.float64), np.ascontiguousarray(x_b, np.float64), cfg)

    estimate.__name__ = name
    estimate.needs_K = name in NEEDS_K  # see fviz.estimators.base.missing_K
    return estimate


# ------------------------------------------------------------------------------ two-view checks


def two_view_configuration(pair, x_a: np.ndarray, x_b: np.ndarray, seed: int = 0) -> str:
    """COLMAP's two-view configuration of the matches, lower case (``planar``, ``uncalibrated``, ...),
    with the pair's cameras and COLMAP's default options (4 px, seeded), the relative pose computed so that
    a plane seen with parallax is ``planar`` and one without (pure rotation) ``panoramic``."""
    import pycolmap

    if len(x_a) < MIN_MATCHES["colmap"]:
        return "degenerate"
    cam_a = pycolmap.Camera(**pinhole(pair.K_a, pair.size_a))
    cam_b = pycolmap.Camera(**pinhole(pair.K_b, pair.size_b))
    cam_a.has_prior_focal_length = cam_b.has_prior_focal_length = True  # K is known: COLMAP's calibrated path
    opt = pycolmap.TwoViewGeometryOptions()
    opt.ransac.random_seed = seed
    opt.compute_relative_pose = True  # resolves planar_or_panoramic into planar or panoramic
    idx = np.repeat(np.arange(len(x_a), dtype=np.uint32)[:, None], 2, axis=1)
    geom = pycolmap.estimate_two_view_geometry(cam_a, np.asarray(x_a, np.float64), cam_b, np.asarray(x_b, np.float64),
                                               idx, opt)
    return pycolmap.TwoViewGeometryConfiguration(geom.config).name.lower()


def bougnoux_focals(F: np.ndarray, pp_a: np.ndarray, pp_b: np.ndarray) -> tuple[float, float]:
    """(f_a, f_b) px of F by Bougnoux's formula (PoseLib), given the principal points (2,); NaN where f^2 < 0.

    Degenerate where the optical axes are (nearly) coplanar, e.g. rectified stereo: then even the true F
    gives arbitrary focals."""
    import poselib

    cam_a, cam_b = poselib.focals_from_fundamental(np.asarray(F, np.float64), np.asarray(pp_a, np.float64).reshape(2, 1),
                                                   np.asarray(pp_b, np.float64).reshape(2, 1))
    return float(cam_a.focal()), float(cam_b.focal())
