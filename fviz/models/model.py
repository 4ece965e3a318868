"""FNet: the paper's networks, all 36 variants.

    FNet(arch, head, pos, norm, input_hw=(96, 320))
    forward(img_a, img_b): (B, 1, H, W) float in [0, 1] x 2 -> F (B, 3, 3)

F satisfies ``x_b^T F x_a = 0`` in pixel coordinates of the model input (H, W) (OpenCV origin) and
is normalized by the chosen layer (etr / fbn / abs).  :func:`fviz.models.predict_F` maps it back to
the pixels of the original images.

Pipeline: backbone (:mod:`.backbones`) -> location-aware pooling (:mod:`.pooling`) -> flatten ->
head (:mod:`.heads`) -> normalization (:mod:`.normalization`), in the input's pixels or, with ``norm_frame``, in
another frame (a raw KITTI drive's unrectified cameras, where rectified stereo's F33 != 0 and ETR is defined; the
output stays in input pixels, only its scale and sign come from that frame).

Variants (``VARIANTS``, 36 names ``{arch}-{head}[-pos]-{norm}``): 2 archs (single, siamese) x the
paper's six heads {Base, POS, EPI, EPI+POS, REC, REC+POS} = {base, base-pos, epi, epi-pos, rec,
rec-pos} x 3 norms (etr, fbn, abs), e.g. "siamese-rec-pos-fbn".

Input size and pooling (why the defaults are what they are)
-----------------------------------------------------------
The paper's layer list applied at full KITTI resolution (376 x 1241) keeps a 128-channel map of
~470k positions up to the FC layer: a 1024-wide FC after it would hold billions of weights.  Here:

- the input is resized to ``input_hw`` = 96 x 320 by default (KITTI's aspect ratio, 1/3.9 scale);
- the single max-pool is an *adaptive* max-pool to a fixed ``pool_grid`` of 3 x 10 windows
  (32 x 32 input pixels each at 96 x 320), so the FC size does not depend on the input size at all;
- with POS, each window also reports where (row, col in [0, 1]) each channel's maximum was: the
  location information survives the large windows;
- the FC has ``hidden`` = 256 units: 128 ch x 3 (POS) x 30 windows x 256 = 2.95 M weights.

Every variant then has at most 3.17 M parameters (12.7 MB in float32, 6.4 MB in float16; the weights
file that training exports is float16); without POS 1.0-1.2 M (4.0-4.8 MB).

Measured with ``benchmarks/bench_models.py`` (REC+POS FBN, CPU ms per pair at batch 1, a quiet
2-core x86 VM, 2 threads / 1 thread):

    input      Siamese          single-stream
    64 x 208   3.3 / 5.1 ms     5.4 / 10.5 ms
    96 x 320   5.6 / 10.4 ms    27.4 / 45.1 ms
    128 x 416  8.9 / 17.1 ms    51.4 / 92.5 ms

Siamese models are well under the 30 ms/pair CPU target at every size; single-stream ones run their
128-channel 1x1 convolution at full input resolution and grow with the pixel count: 96 x 320 is the
largest size where they still meet it (on 2 threads).  Smaller inputs also lose displacement
information (a 2 degree yaw moves the image by ~3 px at 160 px width, ~6 px at 320).  Accuracy with
the same short budget (Siamese REC FBN, 800 steps of 16 synthetic scenes, metrics in one common
128 x 416 frame over 64 validation scenes):

    input      EPI-ABS   EPI-SQR   median SED   (constant straight-ahead F: 1.335 / 3.144 / 4.12 px)
    64 x 208   1.216     2.731     3.76 px
    96 x 320   0.946     1.744     3.38 px

so 96 x 320 is the default: clearly more accurate than 64 x 208 and still 3x under the time target
for the Siamese models.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import torch
from torch import nn

from fviz.errors import FvizError
from fviz.geometry.fundamental import NORMS
from fviz.models.backbones import make_backbone
from fviz.models.heads import make_head
from fviz.models.normalization import make_norm, normalize_in_frame
from fviz.models.pooling import LocationAwarePool

ARCHS = ("single", "siamese")
HEAD_NAMES = ("base", "rec", "epi")
DEFAULT_INPUT_HW = (96, 320)


def variant_name(arch: str, head: str, pos: bool, norm: str) -> str:
    """("siamese", "rec", True, "fbn") -> "siamese-rec-pos-fbn"."""
    return f"{arch}-{head}{'-pos' if pos else ''}-{norm}"


def parse_variant(name: str) -> dict:
    """"siamese-rec-pos-fbn" -> {"arch": "siamese", "head": "rec", "pos": True, "norm": "fbn"}."""
    parts = str(name).strip().lower().split("-")
    pos = "pos" in parts
    rest = [p for p in parts if p != "pos"]
    if len(rest) != 3 or rest[0] not in ARCHS or rest[1] not in HEAD_NAMES or rest[2] not in NORMS or len(parts) != len(rest) + pos:
        raise FvizError(
            f"unknown model variant {name!r}: expected ARCH-HEAD[-pos]-NORM with ARCH in {'/'.join(ARCHS)}, "
            f"HEAD in {'/'.join(HEAD_NAMES)}, NORM in {'/'.join(NORMS)} (e.g. 'siamese-rec-pos-fbn')"
        )
    return {"arch": rest[0], "head": rest[1], "pos": pos, "norm": rest[2]}


def variants() -> list[str]:
    """All 36 variant names: arch x {base, base-pos, epi, epi-pos, rec, rec-pos} x norm."""
    return [
        variant_name(arch, head, pos, norm)
        for arch in ARCHS
        for head in ("base", "epi", "rec")
        for pos in (False, True)
        for norm in NORMS
    ]


VARIANTS: tuple[str, ...] = tuple(variants())


@dataclass(frozen=True)
class FNetConfig:
    """Everything needed to rebuild an FNet (stored in checkpoints)."""

    arch: str = "siamese"
    head: str = "rec"
    pos: bool = True
    norm: str = "fbn"
    input_hw: tuple[int, int] = DEFAULT_INPUT_HW
    width: int = 128
    pool_grid: tuple[int, int] = (3, 10)
    hidden: int = 256
    dropout: float = 0.5
    conditioned: bool = True
    ucn_channels: tuple[int, int, int] = (32, 64, 64)
    # The frame the norm layer normalizes in: () the model input's own pixels; else 18 floats, U_a then U_b row-major
    # (x' = U x, model-input pixels -> that frame), e.g. the unrectified cameras at the input's scale, where a rectified
    # stereo pair's F33 != 0 and ETR is defined (fviz.train.splits.unrectified_frame). The output stays in input pixels.
    norm_frame: tuple[float, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "input_hw", (int(self.input_hw[0]), int(self.input_hw[1])))
        object.__setattr__(self, "norm_frame", tuple(float(v) for v in self.norm_frame))
        if len(self.norm_frame) not in (0, 18):
            raise FvizError(f"model norm_frame must hold 18 numbers (U_a, U_b row-major) or none, got {len(self.norm_frame)}")
        object.__setattr__(self, "pool_grid", (int(self.pool_grid[0]), int(self.pool_grid[1])))
        object.__setattr__(self, "ucn_channels", tuple(int(c) for c in self.ucn_channels))
        parse_variant(self.variant)  # validates arch / head / norm
        if min(self.input_hw) < 8:
            raise FvizError(f"model input size {self.input_hw} is too small (at least 8 x 8)")
        for name in ("width", "hidden", "pool_grid", "ucn_channels"):
            value = getattr(self, name)
            if min(value if isinstance(value, tuple) else (value,)) < 1:
                raise FvizError(f"model {name} must be >= 1, got {value!r}")
        if not 0.0 <= float(self.dropout) < 1.0:
            raise FvizError(f"model dropout must be in [0, 1), got {self.dropout!r}")

    @property
    def variant(self) -> str:
        return variant_name(self.arch, self.head, self.pos, self.norm)

    def to_dict(self) -> dict:
        d = asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: dict) -> FNetConfig:
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise FvizError(f"model config has unknown field(s) {', '.join(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

    @classmethod
    def from_variant(cls, name: str, **kw) -> FNetConfig:
        return cls(**parse_variant(name), **kw)


class FNet(nn.Module):
    """One of the paper's networks.

    forward(img_a, img_b, strict_norm=None): (B, 1, H, W) x 2, float in [0, 1], (H, W) = input_hw
    -> F (B, 3, 3) float32 in model-input pixels, normalized (etr / fbn / abs).
    ``strict_norm`` is passed to the normalization layer (None: strict in eval mode; see
    :mod:`fviz.models.normalization`).
    """

    def __init__(
        self,
        arch: str = "siamese",
        head: str = "rec",
        pos: bool = True,
        norm: str = "fbn",
        input_hw: tuple[int, int] = DEFAULT_INPUT_HW,
        *,
        width: int = 128,
        pool_grid: tuple[int, int] = (3, 10),
        hidden: int = 256,
        dropout: float = 0.5,
        conditioned: bool = True,
        ucn_channels: tuple[int, int, int] = (32, 64, 64),
        norm_frame: tuple[float, ...] = (),
    ):
        super().__init__()
        self.config = FNetConfig(
            arch=arch, head=head, pos=pos, norm=norm, input_hw=tuple(input_hw), width=width, pool_grid=tuple(pool_grid),
            hidden=hidden, dropout=dropout, conditioned=conditioned, ucn_channels=tuple(ucn_channels), norm_frame=tuple(norm_frame),
        )
        c = self.config
        self.backbone = make_backbone(c.arch, c.width, c.ucn_channels)
        self.pool = LocationAwarePool(c.pool_grid, c.pos)
        self.head = make_head(c.head, self.pool.out_features(self.backbone.out_channels), c.input_hw, c.hidden, c.dropout, c.conditioned)
        self.norm = make_norm(c.norm)
        frame = torch.tensor(c.norm_frame or [0.0] * 18, dtype=torch.float64).reshape(2, 3, 3)
        self.register_buffer("norm_frame", frame, persistent=False)  # not in the state: rebuilt from the config

    @classmethod
    def from_config(cls, config: FNetConfig | dict) -> FNet:
        if isinstance(config, dict):
            config = FNetConfig.from_dict(config)
        return cls(**{f.name: getattr(config, f.name) for f in fields(config)})

    @classmethod
    def from_variant(cls, name: str, **kw) -> FNet:
        return cls(**parse_variant(name), **kw)

    @property
    def variant(self) -> str:
        return self.config.variant

    @property
    def input_hw(self) -> tuple[int, int]:
        return self.config.input_hw

    def _check(self, img: torch.Tensor, which: str) -> None:
        H, W = self.config.input_hw
        if img.ndim != 4 or img.shape[1] != 1 or tuple(img.shape[-2:]) != (H, W):
            raise FvizError(
                f"{self.variant}: image {which} must be (B, 1, {H}, {W}) (the model's input size), got {tuple(img.shape)}"
            )

    def features(self, img_a: torch.Tensor, img_b: torch.Tensor) -> torch.Tensor:
        """The head's input: pooled features.  (B, 1, H, W) x 2 -> (B, n_in)."""
        self._check(img_a, "a")
        self._check(img_b, "b")
        return self.pool(self.backbone(img_a, img_b)).flatten(1)

    def unnormalized(self, img_a: torch.Tensor, img_b: torch.Tensor) -> torch.Tensor:
        """F before the normalization layer.  (B, 1, H, W) x 2 -> (B, 3, 3) float32."""
        return self.head(self.features(img_a, img_b))

    def forward(self, img_a: torch.Tensor, img_b: torch.Tensor, strict_norm: bool | None = None) -> torch.Tensor:
        return self._normalized(self.unnormalized(img_a, img_b), strict_norm)

    def indexed(self, images: torch.Tensor, index: torch.Tensor, strict_norm: bool | None = None) -> torch.Tensor:
        """:meth:`forward` of the pairs (images[index[:, 0]], images[index[:, 1]]), what the backbone computes
        per image done once per image (eval mode).  (N, 1, H, W), (B, 2) long -> F (B, 3, 3) float32."""
        self._check(images, "a/b")
        return self._normalized(self.head(self.pool(self.backbone.indexed(images, index)).flatten(1)), strict_norm)

    def _normalized(self, F: torch.Tensor, strict_norm: bool | None) -> torch.Tensor:
        with torch.autocast(device_type=F.device.type, enabled=False):
            if not self.config.norm_frame:
                return self.norm(F.float(), strict=strict_norm)
            strict = (not self.training) if strict_norm is None else strict_norm
            frame = (self.norm_frame[0].float(), self.norm_frame[1].float())
            return normalize_in_frame(F.float(), self.config.norm, frame, strict)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
