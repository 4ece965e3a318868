"""The one image-pair type every source produces (KITTI odometry and raw, synthetic, two image files,
pairs files, COLMAP models). Ground truth is optional: code that needs it asks the pair
(:attr:`Pair.has_gt`, :attr:`Pair.has_pose`, :attr:`Pair.has_K`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

# What a pair's ground truth is, as the JSON's pair.ground_truth says it.
GT_POSE, GT_F, GT_CORRESPONDENCES, GT_NONE = "pose", "F", "correspondences", "none"


@dataclass(frozen=True)
class PairId:
    """Where a pair comes from; enough to reload it (with its source) and to name it.

    ``source`` is "odometry", "raw" or "synthetic" (KITTI frame/camera numbers), or a user source
    ("images", "pairs", "colmap") that names its images: ``image_a`` / ``image_b`` (file names relative
    to the source's image folder), ``frame_a`` / ``frame_b`` then index the source's list (a pairs file's
    line, a COLMAP image id). ``sequence``: the odometry sequence ("00"), the raw drive, the synthetic
    seed, or the user source's label; ``kind``: "stereo" or "temporal" (KITTI, synthetic) or "pair".
    """

    source: str
    sequence: str
    kind: str
    frame_a: int
    frame_b: int
    cam_a: int = 0
    cam_b: int = 0
    root: str = ""
    image_a: str = ""
    image_b: str = ""

    @property
    def named(self) -> bool:
        """Whether the source names its images (user sources) rather than numbering frames and cameras."""
        return bool(self.image_a)

    @property
    def name(self) -> str:
        if self.named:
            return "/".join(p for p in (self.source, self.sequence, f"{self.image_a}--{self.image_b}") if p)
        return f"{self.source}/{self.sequence}/{self.kind}/f{self.frame_a:06d}c{self.cam_a}-f{self.frame_b:06d}c{self.cam_b}"

    @property
    def key_a(self) -> str:
        """Identifies image a (for per-frame feature caches)."""
        if self.named:
            return f"{self.source}/{self.sequence}/{self.image_a}"
        return f"{self.source}/{self.sequence}/c{self.cam_a}/{self.frame_a:06d}"

    @property
    def key_b(self) -> str:
        if self.named:
            return f"{self.source}/{self.sequence}/{self.image_b}"
        return f"{self.source}/{self.sequence}/c{self.cam_b}/{self.frame_b:06d}"

    def to_dict(self) -> dict[str, Any]:
        d = {
            "name": self.name,
            "source": self.source,
            "root": self.root,
            "sequence": self.sequence,
            "kind": self.kind,
            "frame_a": self.frame_a,
            "frame_b": self.frame_b,
            "cam_a": self.cam_a,
            "cam_b": self.cam_b,
        }
        if self.named:
            d.update(image_a=self.image_a, image_b=self.image_b)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "PairId":
        return cls(**{k: v for k, v in d.items() if k != "name"})


class LazyImage:
    """An image not decoded yet (a source's promise): ``load()`` decodes it, ``shape`` is known without
    decoding (from the file's header). A :class:`Pair` decodes it on first access to ``image_a`` / ``image_b``,
    so a pair whose features are at hand (a run's other pair of that frame detected them) decodes nothing."""

    def __init__(self, load, shape: tuple[int, ...]):
        self.load, self.shape = load, tuple(shape)

    @property
    def ndim(self) -> int:
        return len(self.shape)


@dataclass
class Pair:
    """Two images, their cameras if known and the ground truth if known (``x_b^T F_gt x_a = 0``, pixels).

    image_a, image_b: (H, W) uint8 gray or (H, W, 3) uint8 RGB (a source may give a :class:`LazyImage`: decoded
    when first read; ``size_a`` / ``size_b`` never decode).
    K_a, K_b: (3, 3) intrinsics or None.  R, t: motion X_b = R X_a + t from camera a to camera b, or None.
    F_gt: (3, 3), unit Frobenius norm, or None (no ground truth: estimators are compared with each other).
    gt_accuracy_px: how far the ground truth itself can be trusted (None when unknown).
    points_a, points_b: exact correspondences (M, 2) when the source knows them (synthetic), else None.
    gt_points: (x_a, x_b) (M, 2) ground-truth correspondences (``--gt-matches``): the metrics are computed on
    them instead of on the matches near F_gt (which was fitted to them).
    matches: the user's matches (:class:`fviz.data.correspondences.Correspondences`, ``--matches``), used
    instead of fviz's features; None for fviz's own.
    notes: what the source did to the images that a user should know (e.g. a colour image made gray).
    """

    id: PairId
    image_a: np.ndarray
    image_b: np.ndarray
    K_a: np.ndarray | None = None
    K_b: np.ndarray | None = None
    R: np.ndarray | None = None
    t: np.ndarray | None = None
    F_gt: np.ndarray | None = None
    gt_accuracy_px: float | None = None
    points_a: np.ndarray | None = None
    points_b: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    gt_points: tuple[np.ndarray, np.ndarray] | None = None
    matches: Any = None

    @property
    def has_gt(self) -> bool:
        """Whether a ground-truth F is known (every GT-based metric needs it)."""
        return self.F_gt is not None

    @property
    def has_K(self) -> bool:
        return self.K_a is not None and self.K_b is not None

    @property
    def has_pose(self) -> bool:
        """Whether the true relative pose (and the cameras) are known: pose errors need them."""
        return self.has_K and self.R is not None and self.t is not None

    @property
    def ground_truth(self) -> str:
        """What the ground truth is: "pose", "F", "correspondences" or "none"."""
        if not self.has_gt:
            return GT_NONE
        if self.gt_points is not None:
            return GT_CORRESPONDENCES
        return GT_POSE if self.has_pose else GT_F

    @property
    def size_a(self) -> tuple[int, int]:
        """(width, height) of image a."""
        shape = self.__dict__["image_a"].shape  # a LazyImage's too: no decoding
        return int(shape[1]), int(shape[0])

    @property
    def size_b(self) -> tuple[int, int]:
        shape = self.__dict__["image_b"].shape
        return int(shape[1]), int(shape[0])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (no pixels); what is unknown is None."""
        listed = lambda a: None if a is None else np.asarray(a).tolist()  # noqa: E731
        d = {
            **self.id.to_dict(),
            "size_a": list(self.size_a),
            "size_b": list(self.size_b),
            "K_a": listed(self.K_a),
            "K_b": listed(self.K_b),
            "baseline_m": None if self.t is None else float(np.linalg.norm(self.t)),
            "gt_accuracy_px": self.gt_accuracy_px,
            "ground_truth": self.ground_truth,
        }
        if self.id.named:
            for v in ("a", "b"):
                if f"path_{v}" in self.extra:
                    d[f"path_{v}"] = self.extra[f"path_{v}"]
        return d


def _decoded_on_read(name: str) -> property:
    """``Pair.<name>``: the array, a LazyImage decoded (once) when first read."""

    def get(self) -> np.ndarray:
        value = self.__dict__[name]
        if isinstance(value, LazyImage):
            value = self.__dict__[name] = value.load()
        return value

    def set_(self, value) -> None:
        self.__dict__[name] = value

    return property(get, set_, doc=f"{name}: (H, W) or (H, W, 3) uint8, decoded on first read")


Pair.image_a = _decoded_on_read("image_a")
Pair.image_b = _decoded_on_read("image_b")
