"""What features and matching produce, whoever made them (OpenCV's detectors, the learned matchers, a user's file):
:class:`Features` of one image and :class:`Matches` of a pair. Plain types, so that every producer imports them
without importing the others."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Features:
    """keypoints: (N, 2) float64 pixels; descriptors: (N, D); scores: (N,) the detector's responses, or None;
    image_digest: the pixels' digest when a run's feature cache asked for it (taken while they are decoded);
    image_size: (width, height) of the image (learned matchers need it; hloc's features.h5 keeps it)."""

    keypoints: np.ndarray
    descriptors: np.ndarray | None
    scores: np.ndarray | None = None
    image_digest: str | None = None
    image_size: tuple[int, int] | None = None


@dataclass
class Matches:
    """idx: (M, 2) indices into (features_a, features_b); x_a, x_b: (M, 2) pixels; distance: (M,).
    scores: (M,) the matcher's own confidence of a user's matches (``--matches``), else None."""

    idx: np.ndarray
    x_a: np.ndarray
    x_b: np.ndarray
    distance: np.ndarray
    scores: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.idx)

    def take(self, idx: np.ndarray) -> "Matches":
        """The matches at ``idx`` (K,) indices, in that order."""
        return Matches(self.idx[idx], self.x_a[idx], self.x_b[idx], self.distance[idx],
                       None if self.scores is None else self.scores[idx])
