"""What a click needs of one pair, read from a recording (:func:`fviz.record.rebuild.click_pairs`) or made from a result
(:mod:`fviz.interactive`, which draws the click): the record layer's, so that reading a recording needs nothing above it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fviz.record import layout as L


@dataclass
class PairFs:
    """What a click needs of one pair: the F's (ground truth among them, named ``gt``), their colours, the
    image sizes (w, h) and the matches. F: (n, 3, 3); x_a, x_b: (N, 2) in each image's pixels. ``root``: the entity
    the pair is drawn under ("": the recording's root; train.rrd: ``watch/{k}``), its click's marks there too."""

    names: list[str]
    F: np.ndarray
    size_a: tuple[int, int]
    size_b: tuple[int, int]
    x_a: np.ndarray
    x_b: np.ndarray
    colors: dict[str, tuple[int, int, int]] = field(default_factory=dict)
    root: str = ""

    def __post_init__(self):
        self.F = np.asarray(self.F, float).reshape(-1, 3, 3)
        self.x_a = np.asarray(self.x_a, float).reshape(-1, 2)
        self.x_b = np.asarray(self.x_b, float).reshape(-1, 2)
        self.colors = self.colors or L.estimator_colors(self.names)

    def size(self, view: str) -> tuple[int, int]:
        return self.size_a if view == "a" else self.size_b

    def path(self, entity: str) -> str:
        """``entity`` (a layout path: ``b/click``, ...) under the pair's root."""
        return f"{self.root}/{entity}" if self.root else entity

    def ends(self, entity: str) -> bool:
        """Whether ``entity`` draws the match ends (instance i: a's end of match i for i < N, b's of match i - N):
        an estimator's ``layout.matches``, or a watched pair's ``points``."""
        return entity == self.path("points") if self.root else L.matches_owner(entity) is not None
