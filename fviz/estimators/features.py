"""Local features and matching (OpenCV): detect once per image, match with ratio test (+ mutual check)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fviz.errors import FvizError

FEATURES = ("sift", "orb", "akaze")


@dataclass(frozen=True)
class FeatureConfig:
    kind: str = "sift"
    max_keypoints: int = 2000
    ratio: float = 0.8
    mutual: bool = True

    def __post_init__(self):
        if self.kind not in FEATURES:
            raise FvizError(f"--features {self.kind!r}: choose one of {', '.join(FEATURES)}")
        if not 0 < self.ratio <= 1:
            raise FvizError(f"--ratio {self.ratio}: must be in (0, 1]")
        if self.max_keypoints < 8:
            raise FvizError(f"--max-keypoints {self.max_keypoints}: must be >= 8")


@dataclass
class Features:
    """keypoints: (N, 2) float64 pixels; descriptors: (N, D)."""

    keypoints: np.ndarray
    descriptors: np.ndarray | None


@dataclass
class Matches:
    """idx: (M, 2) indices into (features_a, features_b); x_a, x_b: (M, 2) pixels; distance: (M,)."""

    idx: np.ndarray
    x_a: np.ndarray
    x_b: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        return len(self.idx)


def _detector(cfg: FeatureConfig):
    import cv2

    if cfg.kind == "sift":
        return cv2.SIFT_create(nfeatures=cfg.max_keypoints)
    if cfg.kind == "orb":
        return cv2.ORB_create(nfeatures=cfg.max_keypoints)
    return cv2.AKAZE_create()


def detect(image: np.ndarray, cfg: FeatureConfig = FeatureConfig()) -> Features:
    """Keypoints and descriptors of one uint8 image (gray or RGB)."""
    import cv2

    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    kps, desc = _detector(cfg).detectAndCompute(gray, None)
    if cfg.kind == "akaze" and len(kps) > cfg.max_keypoints:
        keep = np.argsort([-k.response for k in kps])[: cfg.max_keypoints]
        kps, desc = [kps[i] for i in keep], desc[keep]
    pts = np.array([k.pt for k in kps], dtype=np.float64).reshape(-1, 2)
    return Features(pts, desc)


def match(fa: Features, fb: Features, cfg: FeatureConfig = FeatureConfig()) -> Matches:
    """Nearest neighbours a -> b with Lowe's ratio test, optionally kept only when mutual."""
    import cv2

    empty = Matches(np.zeros((0, 2), int), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
    if fa.descriptors is None or fb.descriptors is None or len(fa.keypoints) < 2 or len(fb.keypoints) < 2:
        return empty
    norm = cv2.NORM_L2 if fa.descriptors.dtype == np.float32 else cv2.NORM_HAMMING
    bf = cv2.BFMatcher(norm)
    knn = bf.knnMatch(fa.descriptors, fb.descriptors, k=2)
    pairs = [(m[0].queryIdx, m[0].trainIdx, m[0].distance) for m in knn if len(m) == 2 and m[0].distance < cfg.ratio * m[1].distance]
    if not pairs:
        return empty
    ia, ib, dist = (np.array(v) for v in zip(*pairs))
    if cfg.mutual:
        back = bf.match(fb.descriptors, fa.descriptors)
        best_a_for_b = np.full(len(fb.keypoints), -1)
        best_a_for_b[[m.queryIdx for m in back]] = [m.trainIdx for m in back]
        keep = best_a_for_b[ib] == ia
        ia, ib, dist = ia[keep], ib[keep], dist[keep]
    order = np.argsort(dist, kind="stable")  # best first (the 7-point solver takes the first 7)
    ia, ib, dist = ia[order], ib[order], dist[order]
    idx = np.stack([ia, ib], 1).astype(int)
    return Matches(idx, fa.keypoints[ia], fb.keypoints[ib], dist.astype(np.float64))


class FeatureCache:
    """Features per image key (``PairId.key_a``), so frames shared by several pairs are detected once."""

    def __init__(self, cfg: FeatureConfig, max_items: int = 64):
        self.cfg, self.max_items = cfg, max_items
        self._items: dict[str, Features] = {}
        self.hits = self.misses = 0

    def get(self, key: str, image: np.ndarray) -> Features:
        if key in self._items:
            self.hits += 1
            return self._items[key]
        self.misses += 1
        feats = detect(image, self.cfg)
        if len(self._items) >= self.max_items:  # bounded memory: drop the oldest
            self._items.pop(next(iter(self._items)))
        self._items[key] = feats
        return feats
