"""Location-aware pooling (the paper's "POS" variants, Sec. 3.1).

A max-pool keeps the strongest response of each channel in each pooling window but forgets *where*
it was; the position of image features is what a fundamental matrix is about.  With ``pos=True`` the
argmax of every window is turned into its (row, col) in the feature map, normalized to [0, 1]
(row / (h - 1), col / (w - 1)), and appended as two more channels per feature channel:

    (B, C, h, w) -> max values (B, C, gh, gw) ++ rows (B, C, gh, gw) ++ cols (B, C, gh, gw)
                 =  (B, 3C, gh, gw)

Without ``pos`` it is a plain max-pool: (B, C, h, w) -> (B, C, gh, gw).

The pool is *adaptive*: it always produces a fixed ``grid`` = (gh, gw) of windows whatever the
feature map size, so the fully connected layer after it has the same size for every input
resolution.  Its windows are large (e.g. 32 x 32 input pixels for a 96 x 320 input and a 3 x 10
grid), which is what keeps the FC layer small; the position channels keep the sub-window location
of each maximum that a large plain pool would throw away.  The indices carry no gradient (they are
piecewise constant); the max values do.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class LocationAwarePool(nn.Module):
    """Adaptive max-pool to ``grid`` windows, with the argmax positions appended when ``pos``.

    forward: (B, C, h, w) -> (B, C * (3 if pos else 1), gh, gw).
    """

    def __init__(self, grid: tuple[int, int] = (3, 10), pos: bool = True):
        super().__init__()
        self.grid = (int(grid[0]), int(grid[1]))
        self.pos = bool(pos)

    def out_features(self, channels: int) -> int:
        """Length of the flattened output for ``channels`` input channels."""
        return channels * (3 if self.pos else 1) * self.grid[0] * self.grid[1]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.pos:
            return F.adaptive_max_pool2d(x, self.grid)
        h, w = x.shape[-2:]
        values, idx = F.adaptive_max_pool2d(x, self.grid, return_indices=True)  # idx into h * w
        rows = torch.div(idx, w, rounding_mode="floor").to(values.dtype) / max(h - 1, 1)
        cols = torch.remainder(idx, w).to(values.dtype) / max(w - 1, 1)
        return torch.cat([values, rows, cols], dim=1)

    def extra_repr(self) -> str:
        return f"grid={self.grid}, pos={self.pos}"
