"""Classical estimators from matches, all through OpenCV (points1 = x_a, points2 = x_b, so x_b^T F x_a = 0).

What ``--threshold`` (px) means to each (measured: the returned masks equal these tests on KITTI pairs):

- ``ransac`` (FM_RANSAC): the larger of the two point-to-epipolar-line distances, < threshold;
- ``magsac`` and the ``usac-*`` family: the Sampson distance, < threshold (MAGSAC++ marginalizes over noise
  scales up to it, so it is a maximum rather than a cut);
- ``lmeds``: none (least median of squares); ``7point`` / ``8point``: only their reported inlier mask.

``usac-*`` are OpenCV's USAC presets as image-matching-webui offers them (``cv2.USAC_DEFAULT`` ...): the flag
API fixes OpenCV's random state, so they are deterministic but ignore ``--seed``; ``usac-parallel`` runs
several threads and may differ between runs. ``ransac`` and ``lmeds`` ignore ``--seed`` too (OpenCV's RANSAC
makes its own generator at a fixed state; ``cv2.setRNGSeed`` does not reach it); only ``magsac`` takes it.
``usac-prosac`` samples the best matches first: fviz's matches come best first (ascending descriptor distance),
the order PROSAC needs.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from fviz.errors import FvizError
from fviz.geometry import sampson_distance

USAC_FLAGS = {"usac-default": "USAC_DEFAULT", "usac-accurate": "USAC_ACCURATE", "usac-prosac": "USAC_PROSAC",
              "usac-fm8pts": "USAC_FM_8PTS", "usac-parallel": "USAC_PARALLEL"}
MIN_MATCHES = {"7point": 7, "8point": 8, "lmeds": 8, "ransac": 8, "magsac": 8, **dict.fromkeys(USAC_FLAGS, 8)}


@dataclass(frozen=True)
class RobustConfig:
    """threshold: inlier distance in px; confidence in (0, 1] (1: run to max_iters); max_iters: iteration cap; seed: RNG seed."""

    threshold: float = 1.0
    confidence: float = 0.999
    max_iters: int = 10000
    seed: int = 0

    def __post_init__(self):
        if self.threshold <= 0:
            raise FvizError(f"--threshold {self.threshold}: must be > 0")
        if not 0 < self.confidence <= 1:
            raise FvizError(f"--confidence {self.confidence}: must be in (0, 1]")
        if self.max_iters < 1:
            raise FvizError(f"--max-iters {self.max_iters}: must be >= 1")


def _check(name: str, x_a: np.ndarray) -> None:
    need = MIN_MATCHES[name]
    if len(x_a) < need:
        raise ValueError(f"{name} needs at least {need} matches, got {len(x_a)}")


def _first_solution(F: np.ndarray | None) -> np.ndarray | None:
    return None if F is None or F.size < 9 else F[:3]


def _threshold_mask(F: np.ndarray, x_a: np.ndarray, x_b: np.ndarray, threshold: float) -> np.ndarray:
    return sampson_distance(F, x_a, x_b) < threshold


def seven_point(x_a, x_b, cfg: RobustConfig):
    """The minimal solver on the 7 best matches (lowest descriptor distance, as given first);
    of its up to 3 solutions, the one with the lowest median Sampson error on all matches."""
    import cv2

    _check("7point", x_a)
    F, _ = cv2.findFundamentalMat(x_a[:7], x_b[:7], cv2.FM_7POINT)
    if F is None:
        return None
    candidates = F.reshape(-1, 3, 3)
    best = min(candidates, key=lambda c: float(np.nanmedian(sampson_distance(c, x_a, x_b))))
    return best, _threshold_mask(best, x_a, x_b, cfg.threshold)


def eight_point(x_a, x_b, cfg: RobustConfig):
    """Normalized 8-point (Hartley) least squares on all matches; inliers by Sampson threshold."""
    import cv2

    _check("8point", x_a)
    F, _ = cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)
    F = _first_solution(F)
    return (None if F is None else (F, _threshold_mask(F, x_a, x_b, cfg.threshold)))


def _opencv_robust(method_flag: int, name: str):
    """An OpenCV robust method by flag (FM_RANSAC, FM_LMEDS, USAC_*): each fixes its own random state (no seed)."""

    def estimate(x_a, x_b, cfg: RobustConfig):
        import cv2

        _check(name, x_a)
        F, mask = cv2.findFundamentalMat(x_a, x_b, method_flag, cfg.threshold, cfg.confidence, cfg.max_iters)
        F = _first_solution(F)
        return None if F is None else (F, mask.ravel().astype(bool))

    estimate.__name__ = name
    return estimate


def magsac(x_a, x_b, cfg: RobustConfig):
    """MAGSAC++ through OpenCV's USAC framework, seeded."""
    import cv2

    _check("magsac", x_a)
    p = cv2.UsacParams()
    p.sampler = cv2.SAMPLING_UNIFORM
    p.score = cv2.SCORE_METHOD_MAGSAC
    p.loMethod = cv2.LOCAL_OPTIM_SIGMA
    p.loIterations = 10
    p.loSampleSize = 50
    p.final_polisher = cv2.MAGSAC
    p.final_polisher_iterations = 20
    p.neighborsSearch = cv2.NEIGH_GRID
    p.threshold = cfg.threshold
    p.confidence = cfg.confidence
    p.maxIterations = cfg.max_iters
    p.randomGeneratorState = cfg.seed
    p.isParallel = False
    F, mask = cv2.findFundamentalMat(x_a, x_b, p)
    F = _first_solution(F)
    return None if F is None else (F, mask.ravel().astype(bool))


@functools.cache
def _methods():
    import cv2

    return {
        "7point": seven_point,
        "8point": eight_point,
        "lmeds": _opencv_robust(cv2.FM_LMEDS, "lmeds"),
        "ransac": _opencv_robust(cv2.FM_RANSAC, "ransac"),
        "magsac": magsac,
        **{name: _opencv_robust(getattr(cv2, flag), name) for name, flag in USAC_FLAGS.items()},
    }


def classical(name: str, cfg: RobustConfig = RobustConfig()):
    """An estimator (pair, x_a, x_b) -> (F, inliers) for one of ``MIN_MATCHES``' names (OpenCV is imported at
    the first estimate: a run validates its estimators in the main process, which never estimates)."""
    if name not in MIN_MATCHES:
        raise KeyError(name)

    def estimate(pair, x_a, x_b):
        return _methods()[name](np.ascontiguousarray(x_a, np.float64), np.ascontiguousarray(x_b, np.float64), cfg)

    estimate.__name__ = name
    return estimate
