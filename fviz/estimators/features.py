"""Local features and matching (OpenCV): detect once per image, match with ratio test (+ mutual check)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from fviz.errors import FvizError
from fviz.estimators.keypoints import Features, Matches  # noqa: F401 (re-exported)

from fviz.estimators.learned import LEARNED, is_learned

FEATURES = ("sift", "orb", "akaze") + LEARNED  # the learned ones need the learned extra (fviz.estimators.learned)


@dataclass(frozen=True)
class FeatureConfig:
    kind: str = "sift"
    max_keypoints: int = 2000
    ratio: float = 0.8
    mutual: bool = True

    def __post_init__(self):
        if self.kind not in FEATURES:
            raise FvizError(f"--features {self.kind!r}: choose one of {', '.join(FEATURES)}")
        if is_learned(self.kind):
            from fviz.estimators.learned import require

            require(self.kind)
        if not 0 < self.ratio <= 1:
            raise FvizError(f"--ratio {self.ratio}: must be in (0, 1]")
        if self.max_keypoints < 8:
            raise FvizError(f"--max-keypoints {self.max_keypoints}: must be >= 8")


def user_matches(c) -> Matches:
    """A user's matches (:class:`fviz.data.correspondences.Correspondences`) as Matches, best first when
    they have scores (the 7-point solver takes the first 7), in file order otherwise. ``distance`` is
    1 - score (0 without scores); ``idx`` the rows of the file."""
    n = len(c.x_a)
    order = np.arange(n) if c.scores is None else np.argsort(-np.asarray(c.scores, float), kind="stable")
    scores = None if c.scores is None else np.asarray(c.scores, float)[order]
    distance = np.zeros(n) if scores is None else 1.0 - scores
    return Matches(np.stack([order, order], 1), np.asarray(c.x_a, float)[order], np.asarray(c.x_b, float)[order], distance, scores)


# What changed the keypoints a detector makes, per kind (fviz.run.hloc_cache's settings carry it, so that a run's
# features.h5 written by an older fviz is detected again, never mixed with the new ones). sift 2: precise
# upscaling (issue 43: OpenCV's default put every keypoint +0.25 px right and down of the pixel-centre convention).
DETECTOR_VERSIONS = {"sift": 2}


def _detector(cfg: FeatureConfig):
    import cv2

    if cfg.kind == "sift":
        # OpenCV doubles the image for the first octave by default with a half-pixel error of its own: every keypoint
        # lands +0.25 px right and down of fviz's convention (pixel centres at integers; Gaussian blobs at known
        # centres measure +0.250 / +0.251 px). The precise upscaling keeps the centres (-0.001 px).
        return cv2.SIFT_create(nfeatures=cfg.max_keypoints, enable_precise_upscale=True)
    if cfg.kind == "orb":
        return cv2.ORB_create(nfeatures=cfg.max_keypoints)
    return cv2.AKAZE_create()


def detect(image: np.ndarray, cfg: FeatureConfig = FeatureConfig()) -> Features:
    """Keypoints and descriptors of one uint8 image (gray or RGB)."""
    if is_learned(cfg.kind):
        from fviz.estimators.learned import detect_many

        return detect_many([image], cfg.kind, cfg.max_keypoints)[0]
    import cv2

    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    kps, desc = _detector(cfg).detectAndCompute(gray, None)
    if cfg.kind == "akaze" and len(kps) > cfg.max_keypoints:
        keep = np.argsort([-k.response for k in kps])[: cfg.max_keypoints]
        kps, desc = [kps[i] for i in keep], desc[keep]
    pts = np.array([k.pt for k in kps], dtype=np.float64).reshape(-1, 2)
    return Features(pts, desc, np.array([k.response for k in kps], dtype=np.float32))


MATCH_BLOCK = 256  # rows of the distance matrix at a time: reductions over a block that stays in cache


def _l2_nearest_two(da: np.ndarray, db: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nearest and second-nearest rows of ``db`` for each row of ``da`` by L2 distance, from one GEMM.

    da: (Na, D), db: (Nb, D) float32.  Returns best (Na,) int, d1, d2 (Na,) float32 distances and
    mutual (Na,) bool: row i is also the nearest row of ``da`` for ``db[best[i]]``. Ties go to the
    lowest index, as in OpenCV's brute-force matcher.

    The squared distances come straight out of BLAS: [a, 1, |a|^2] . [-2b, |b|^2, 1]^T = |a - b|^2.
    SIFT descriptors are integers <= 255 whose squared norms are ~512^2, so every partial sum is an
    integer below 2^24 and float32 holds it exactly, in any summation order: the distances, hence the
    matches, equal OpenCV's. The matrix is made MATCH_BLOCK rows at a time (each block's reductions run
    while it is in cache); per block: each row's nearest and, without it, its second nearest, and the
    column minima with and without the rows' nearest entries, which finds the columns whose minimum several
    rows reach (ties, recomputed exactly for those columns alone).
    """
    n_a, dim = da.shape
    n_b = len(db)
    qa = np.empty((n_a, dim + 2), np.float32)
    qb = np.empty((dim + 2, n_b), np.float32)  # transposed: the GEMM's right operand, contiguous
    qa[:, :dim], qa[:, dim] = da, 1.0
    qa[:, dim + 1] = np.einsum("ij,ij->i", da, da)
    np.multiply(db.T, -2.0, out=qb[:dim])
    qb[dim] = np.einsum("ij,ij->i", db, db)
    qb[dim + 1] = 1.0
    best = np.empty(n_a, np.intp)
    first, second = np.empty(n_a, np.float32), np.empty(n_a, np.float32)
    col_min, col_rest = np.full(n_b, np.inf, np.float32), np.full(n_b, np.inf, np.float32)
    buf = np.empty((min(MATCH_BLOCK, n_a), n_b), np.float32)
    for s in range(0, n_a, MATCH_BLOCK):
        d2 = np.matmul(qa[s:s + MATCH_BLOCK], qb, out=buf[: min(MATCH_BLOCK, n_a - s)])  # squared distances
        rows = np.arange(len(d2))
        near = best[s:s + len(d2)] = d2.argmin(1)
        first[s:s + len(d2)] = d2[rows, near]
        np.minimum(col_min, d2.min(0), out=col_min)
        d2[rows, near] = np.inf  # the second nearest is the nearest of the rest
        second[s:s + len(d2)] = d2.min(1)
        np.minimum(col_rest, d2.min(0), out=col_rest)
    rows = np.arange(n_a)
    mutual = first == col_min[best]
    # A column's minimum reached by several rows (ties): by several rows whose nearest it is (``owners``), or
    # also by a row off its own nearest (the column's minimum without the nearest entries equals it).
    owners = np.bincount(best[mutual], minlength=n_b)
    ties = np.flatnonzero((owners > 1) | ((owners > 0) & (col_rest == col_min)))
    if len(ties):
        back = np.full(n_b, -1)
        columns = qa @ qb[:, ties]  # (Na, T): the same integers as in the blocks
        for k, j in enumerate(ties):  # the lowest row reaching the minimum, as OpenCV's cross-check keeps
            own = rows[mutual & (best == j)]
            other = np.flatnonzero((columns[:, k] == col_min[j]) & (best != j))
            back[j] = min(own[0], other[0]) if len(other) else own[0]
        tied = back[best] >= 0
        mutual[tied] &= back[best[tied]] == rows[tied]
    return best, np.sqrt(np.maximum(first, 0)), np.sqrt(np.maximum(second, 0)), mutual  # (rounding of non-integer descriptors)


def _hamming_nearest_two(da: np.ndarray, db: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """As :func:`_l2_nearest_two` for binary descriptors, through OpenCV's Hamming matcher."""
    import cv2

    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    knn = [m if len(m) == 2 else None for m in bf.knnMatch(da, db, k=2)]
    best = np.array([m[0].trainIdx if m else -1 for m in knn])
    d1 = np.array([m[0].distance if m else np.inf for m in knn], float)
    d2 = np.array([m[1].distance if m else np.inf for m in knn], float)
    back = np.full(len(db), -1)
    for m in bf.match(db, da):
        back[m.queryIdx] = m.trainIdx
    return best, d1, d2, (best >= 0) & (back[np.maximum(best, 0)] == np.arange(len(best)))


def match(fa: Features, fb: Features, cfg: FeatureConfig = FeatureConfig()) -> Matches:
    """Nearest neighbours a -> b with Lowe's ratio test, optionally kept only when mutual; best first.
    Learned features: their own matcher (:func:`fviz.estimators.learned.match`; ratio and mutual unused)."""
    if is_learned(cfg.kind):
        from fviz.estimators.learned import match as learned_match

        return learned_match(fa, fb, cfg.kind)
    if fa.descriptors is None or fb.descriptors is None or len(fa.keypoints) < 2 or len(fb.keypoints) < 2:
        return Matches(np.zeros((0, 2), int), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
    da, db = fa.descriptors, fb.descriptors
    nearest_two = _l2_nearest_two if da.dtype == np.float32 else _hamming_nearest_two
    best, d1, d2, mutual = nearest_two(da, db)
    d1, d2 = d1.astype(np.float64), d2.astype(np.float64)  # the ratio test as OpenCV users write it
    keep = (best >= 0) & (d1 < cfg.ratio * d2)
    if cfg.mutual:
        keep &= mutual
    ia = np.flatnonzero(keep)
    order = np.argsort(d1[ia], kind="stable")  # best first (the 7-point solver takes the first 7)
    ia = ia[order]
    ib = best[ia]
    return Matches(np.stack([ia, ib], 1), fa.keypoints[ia], fb.keypoints[ib], d1[ia])


class FeatureCache:
    """Features per image key (``PairId.key_a``), so frames shared by several pairs are detected once.

    ``misses`` counts detections, ``hits`` reuses. A run's scheduler hands a worker the features other
    workers detected (:meth:`put`, not a detection) and takes back the ones later pairs need (:meth:`peek`).
    ``threads``: two missing images of one pair are detected in parallel when > 1. ``fingerprint``: a digest
    of the pixels, kept with the features it detects (``Features.image_digest``; a run's feature cache needs it,
    and the pixels are decoded only to detect).
    """

    def __init__(self, cfg: FeatureConfig, max_items: int = 64, threads: int = 2,
                 fingerprint: Callable[[np.ndarray], str] | None = None):
        self.cfg, self.max_items, self.threads, self.fingerprint = cfg, max_items, threads, fingerprint
        self._items: dict[str, Features] = {}
        self.hits = self.misses = 0

    def _detect(self, image) -> Features:
        image = _array(image)
        f = detect(image, self.cfg)
        if self.fingerprint is not None:
            f.image_digest = self.fingerprint(image)
        return f

    def get(self, key: str, image) -> Features:
        """The features of ``image``: an array, or a function giving it (called only to detect)."""
        if key in self._items:
            self.hits += 1
            return self._items[key]
        self.misses += 1
        return self.put({key: self._detect(image)})[key]

    def put(self, items: dict[str, Features]) -> dict[str, Features]:
        """Store features, dropping the oldest beyond ``max_items`` (bounded memory)."""
        self._items.update(items)
        while len(self._items) > self.max_items:
            self._items.pop(next(iter(self._items)))
        return items

    def peek(self, key: str) -> Features | None:
        return self._items.get(key)

    def clear(self) -> None:
        self._items.clear()

    def get_pair(self, key_a: str, image_a, key_b: str, image_b) -> tuple[Features, Features]:
        """Both images' features (images as in :meth:`get`); two missing ones are detected in parallel (OpenCV
        releases the GIL)."""
        if key_a not in self._items and key_b not in self._items and key_a != key_b and is_learned(self.cfg.kind):
            from fviz.estimators.learned import detect_many  # one batch (one forward pass) for both

            ia, ib = _array(image_a), _array(image_b)
            fa, fb = detect_many([ia, ib], self.cfg.kind, self.cfg.max_keypoints)
            if self.fingerprint is not None:
                fa.image_digest, fb.image_digest = self.fingerprint(ia), self.fingerprint(ib)
            self.misses += 2
            self.put({key_a: fa, key_b: fb})
            return fa, fb
        if self.threads < 2 or key_a in self._items or key_b in self._items or key_a == key_b:
            return self.get(key_a, image_a), self.get(key_b, image_b)
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(2) as pool:
            fb = pool.submit(self._detect, image_b)
            fa = self._detect(image_a)
            fb = fb.result()
        self.misses += 2
        self.put({key_a: fa, key_b: fb})
        return fa, fb


def _array(image) -> np.ndarray:
    """An image given as an array or as a function returning it (decoded only when needed)."""
    return image() if callable(image) else image
