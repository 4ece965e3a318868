"""Feature extractors of the paper (Sec. 3.1): single-stream and Siamese.

Both take the two gray images at the model's input size and return one feature map that the
location-aware pooling (:mod:`fviz.models.pooling`) reduces before the fully connected head.

- :class:`SingleStream` is the paper's single-stream block: a 3x3 convolution with ``width`` (128)
  filters, ReLU, BatchNorm, then a 1x1 convolution with ``width`` filters, ReLU, BatchNorm.
  (The paper's single max-pool is the pooling module that follows.)
- :class:`SingleBackbone` applies it to the two images concatenated across channels:
  (B, 1, H, W) x 2 -> (B, 2, H, W) -> (B, width, H, W).  Stride 1.
- :class:`SiameseBackbone` applies one UCN-like stream (shared weights, no spatial transformer) to
  each image, concatenates the two feature maps and feeds them to the single-stream block:
  (B, 1, H, W) x 2 -> 2 x (B, C, H/4, W/4) -> (B, 2C, H/4, W/4) -> (B, width, H/4, W/4).  Stride 4.
  The stream is ``conv5x5/2 -> conv3x3/2 -> conv3x3`` (channels ``ucn_channels``), each followed by
  ReLU and BatchNorm: the first layers of a UCN-style fully convolutional feature extractor, kept
  small so that a pair runs in a few milliseconds on a CPU.

Layer order is conv -> ReLU -> BatchNorm everywhere, as the paper lists it.
"""

from __future__ import annotations

import torch
from torch import nn


class ConvReluBN(nn.Sequential):
    """conv (k x k, stride s, 'same' padding) -> ReLU -> BatchNorm.  (B, C_in, H, W) -> (B, C_out, H/s, W/s)."""

    def __init__(self, c_in: int, c_out: int, kernel: int, stride: int = 1):
        super().__init__(
            nn.Conv2d(c_in, c_out, kernel, stride=stride, padding=kernel // 2),
            nn.ReLU(inplace=True),
            nn.BatchNorm2d(c_out),
        )


class SingleStream(nn.Sequential):
    """The paper's single-stream block.  (B, c_in, H, W) -> (B, width, H, W)."""

    def __init__(self, c_in: int, width: int = 128):
        super().__init__(ConvReluBN(c_in, width, 3), ConvReluBN(width, width, 1))
        self.out_channels = width


class UCNStream(nn.Sequential):
    """One Siamese stream (UCN-like, no spatial transformer).  (B, 1, H, W) -> (B, C, ceil(H/4), ceil(W/4))."""

    def __init__(self, channels: tuple[int, int, int] = (32, 64, 64)):
        c1, c2, c3 = channels
        super().__init__(ConvReluBN(1, c1, 5, 2), ConvReluBN(c1, c2, 3, 2), ConvReluBN(c2, c3, 3, 1))
        self.out_channels = c3


class SingleBackbone(nn.Module):
    """Images concatenated across channels, then the single-stream block.

    forward: img_a, img_b (B, 1, H, W) -> (B, width, H, W).
    """

    stride = 1

    def __init__(self, width: int = 128):
        super().__init__()
        self.block = SingleStream(2, width)
        self.out_channels = width

    def forward(self, img_a: torch.Tensor, img_b: torch.Tensor) -> torch.Tensor:
        return self.block(torch.cat([img_a, img_b], dim=1))

    def indexed(self, images: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
        """:meth:`forward` of the pairs (images[index[:, 0]], images[index[:, 1]]).  (N, 1, H, W), (B, 2) -> (B, width, H, W)."""
        return self(images[index[:, 0]], images[index[:, 1]])


class SiameseBackbone(nn.Module):
    """Shared-weight UCN-like streams, features concatenated, then the single-stream block.

    forward: img_a, img_b (B, 1, H, W) -> (B, width, ceil(H/4), ceil(W/4)).
    """

    stride = 4

    def __init__(self, width: int = 128, ucn_channels: tuple[int, int, int] = (32, 64, 64)):
        super().__init__()
        self.stream = UCNStream(ucn_channels)
        self.block = SingleStream(2 * self.stream.out_channels, width)
        self.out_channels = width

    def forward(self, img_a: torch.Tensor, img_b: torch.Tensor) -> torch.Tensor:
        # one pass of the shared stream over the stacked batch (2B): the same weights for both
        # images, and BatchNorm statistics taken over images a and b alike
        feats = self.stream(torch.cat([img_a, img_b], dim=0))
        f_a, f_b = feats.chunk(2, dim=0)
        return self.block(torch.cat([f_a, f_b], dim=1))

    def indexed(self, images: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
        """:meth:`forward` of the pairs (images[index[:, 0]], images[index[:, 1]]), each image's stream run once
        (an image in several pairs, e.g. a pair and its reverse).  (N, 1, H, W), (B, 2) -> (B, width, H/4, W/4).
        In eval mode only: in training BatchNorm's statistics would be taken over the N images, not the 2B."""
        feats = self.stream(images)
        return self.block(torch.cat([feats[index[:, 0]], feats[index[:, 1]]], dim=1))


def make_backbone(arch: str, width: int = 128, ucn_channels: tuple[int, int, int] = (32, 64, 64)) -> nn.Module:
    if arch == "single":
        return SingleBackbone(width)
    if arch == "siamese":
        return SiameseBackbone(width, tuple(ucn_channels))
    raise ValueError(f"unknown arch {arch!r}")
