"""Training data: (img_a, img_b, F_target) at the model's input size.

Every dataset here is indexed by a *list* of indices and returns a whole batch

    ds[[i, j, ...]] -> img_a (B, 1, H, W) float32 in [0, 1], img_b (B, 1, H, W), F (B, 3, 3) float32

with F in pixel coordinates of the (H, W) model input (``x_b^T F x_a = 0``), normalized with the
model's norm (etr / fbn / abs, :func:`fviz.geometry.normalize`).  The loop feeds lists of indices
(:func:`fviz.train.runtime.epoch_batches`) through a ``DataLoader(batch_size=None)``, so workers build whole batches.

- :class:`SyntheticPairs`: scenes from :func:`fviz.data.synthetic.render_batch`, one seed per index,
  rendered directly at the input size (no resize: its F is already in input pixels).  With
  ``num_workers = 0`` batches are rendered in the main process on the training device (GPU
  rendering); with workers, on the CPU in the workers.
- :class:`KittiPairs`: KITTI pairs through :mod:`fviz.data.kitti` (``open_dataset`` and
  ``KittiSequence.load``), from one or several roots (``data.root`` + ``data.roots``), odometry
  sequences and raw drives, temporal pairs of several ``steps`` and stereo / cross-camera pairs of
  the ``cameras`` present (frames counted per camera folder: colour-only sequences work), gray or
  colour (converted to gray), optionally both directions.  The full-resolution images are cropped
  / resized / flipped (:class:`Augment`, every map exact: F' = A_b^-T F A_a^-1) to the input size;
  pairs whose ground truth disagrees with the images can be dropped (``data.max_gt_sed_px``,
  :func:`fviz.train.splits.gt_agreement_px`).
- :class:`TensorPairs`: pairs already in memory (tests, benchmarks);
- :class:`CachedPairs` (``data.cache = true``): any of the above rendered / loaded once into
  memory as uint8, so that later epochs cost no rendering or PNG decoding.

Which pairs a recipe trains and validates on: :mod:`fviz.train.splits` (:func:`~fviz.train.splits.make_datasets`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from fviz.errors import FvizError
from fviz.geometry.fundamental import NormalizationError, normalize
from fviz.train.augment import Augment, augmented_pair
from fviz.train.recipe import scene_config, synthetic_api

MAX_CACHED_FRAMES = 4000  # decoded KITTI frames kept per process (~1.9 GB at 1242 x 375)


def normalize_target(F: np.ndarray, norm: str, what: str, frame: tuple[float, ...] = ()) -> np.ndarray:
    """numpy normalize with a message naming the pair when ETR is undefined.  ``frame``: the model's
    ``norm_frame`` (18 floats, U_a and U_b): normalized there, as the network's layer does
    (:func:`fviz.models.normalization.normalize_in_frame`)."""
    try:
        if not frame:
            return normalize(F, norm)
        from fviz.models.normalization import normalize_in_frame

        U = torch.tensor(frame, dtype=torch.float64).reshape(2, 3, 3)
        return normalize_in_frame(torch.from_numpy(np.asarray(F, np.float64)), norm, (U[0], U[1])).numpy()
    except NormalizationError:
        raise FvizError(
            f"{what}: ETR normalization is undefined for its ground-truth F (F33 ~ 0, e.g. rectified stereo); "
            "train an fbn or abs variant on these pairs, use temporal pairs, or (raw stereo) model.norm_frame = 'unrectified'"
        ) from None


def _as_indices(idx: Any) -> list[int]:
    if isinstance(idx, (int, np.integer)):
        return [int(idx)]
    return [int(i) for i in idx]


class TensorPairs(torch.utils.data.Dataset):
    """In-memory pairs.  img_a, img_b (N, 1, H, W) float in [0, 1]; F (N, 3, 3) already normalized."""

    def __init__(self, img_a: torch.Tensor, img_b: torch.Tensor, F: torch.Tensor):
        if not (len(img_a) == len(img_b) == len(F)):
            raise ValueError("img_a, img_b and F must have the same length")
        self.img_a, self.img_b, self.F = img_a.float(), img_b.float(), F.float()

    def __len__(self) -> int:
        return len(self.F)

    def __getitem__(self, idx):
        i = torch.as_tensor(_as_indices(idx), dtype=torch.long)
        return self.img_a[i], self.img_b[i], self.F[i]


class CachedPairs(torch.utils.data.Dataset):
    """Every pair of ``source`` loaded once into memory: images as uint8 (N, 1, H, W), F float32.

    Synthetic images are exact multiples of 1/255, so caching them is lossless; resized KITTI images
    are rounded to the nearest grey level.  Memory: 2 * N * H * W bytes (60k pairs at 96 x 320: 3.7 GB).
    Loading uses ``num_workers`` processes; ``on_batch(done, total)`` reports progress.
    """

    def __init__(self, source, batch_size: int = 64, num_workers: int = 0, on_batch=None):
        n = len(source)
        batches = [list(range(i, min(i + batch_size, n))) for i in range(0, n, batch_size)]
        loader = torch.utils.data.DataLoader(source, batch_size=None, sampler=batches, num_workers=num_workers)
        self.img_a = self.img_b = self.F = None
        for k, (a, b, F) in enumerate(loader):
            if self.img_a is None:
                self.img_a = torch.empty((n, *a.shape[1:]), dtype=torch.uint8)
                self.img_b = torch.empty((n, *b.shape[1:]), dtype=torch.uint8)
                self.F = torch.empty((n, 3, 3), dtype=torch.float32)
            idx = torch.as_tensor(batches[k])
            self.img_a[idx] = (a.float().cpu() * 255.0).round().clamp(0, 255).to(torch.uint8)
            self.img_b[idx] = (b.float().cpu() * 255.0).round().clamp(0, 255).to(torch.uint8)
            self.F[idx] = F.float().cpu()
            if on_batch is not None:
                on_batch(min((k + 1) * batch_size, n), n)
        if self.F is None:
            self.F = torch.empty((0, 3, 3))

    def __len__(self) -> int:
        return len(self.F)

    @property
    def nbytes(self) -> int:
        return sum(t.numel() * t.element_size() for t in (self.img_a, self.img_b, self.F) if t is not None)

    def to(self, device: str | torch.device) -> CachedPairs:
        """Move the cache (e.g. onto the GPU: batches are then gathered there, no host copies)."""
        for name in ("img_a", "img_b", "F"):
            if getattr(self, name) is not None:
                setattr(self, name, getattr(self, name).to(device))
        return self

    def __getitem__(self, idx):
        i = torch.as_tensor(_as_indices(idx), dtype=torch.long, device=self.F.device)
        return self.img_a[i].float() / 255.0, self.img_b[i].float() / 255.0, self.F[i]


class SyntheticPairs(torch.utils.data.Dataset):
    """Synthetic scenes, one seed per index.  ds[list] -> batch (see module docstring)."""

    def __init__(self, seeds: Sequence[int], input_hw: tuple[int, int], norm: str, extra: dict | None = None,
                 render_device: str | torch.device = "cpu"):
        self.seeds = list(seeds)
        self.input_hw = (int(input_hw[0]), int(input_hw[1]))
        self.norm = norm
        self.extra = dict(extra or {})
        self.render_device = torch.device(render_device)
        self._config = None

    def __len__(self) -> int:
        return len(self.seeds)

    def __getstate__(self):  # workers rebuild the config (and render on the CPU)
        state = dict(self.__dict__)
        state["_config"] = None
        state["render_device"] = torch.device("cpu")
        return state

    def __getitem__(self, idx):
        from fviz.models.normalization import normalize_f

        synthetic = synthetic_api()
        if self._config is None:
            self._config = scene_config(self.input_hw, self.extra)
        seeds = [self.seeds[i] for i in _as_indices(idx)]
        out = synthetic.render_batch(seeds, self._config, self.render_device)
        img_a = torch.as_tensor(out["image_a"]).float()
        img_b = torch.as_tensor(out["image_b"]).float()
        F = torch.as_tensor(out["F"]).to(img_a.device, torch.float64)
        H, W = self.input_hw
        if tuple(img_a.shape[-3:]) != (1, H, W) or tuple(img_b.shape[-3:]) != (1, H, W):
            raise FvizError(f"fviz.data.synthetic.render_batch returned images {tuple(img_a.shape)}, expected (B, 1, {H}, {W})")
        try:
            F = normalize_f(F, self.norm, strict=True)
        except NormalizationError:
            raise FvizError(
                f"synthetic seeds {seeds[0]}..{seeds[-1]}: ETR normalization is undefined for a ground-truth F "
                "(F33 ~ 0); train an fbn or abs variant, or change data.synthetic"
            ) from None
        return img_a, img_b, F.float()


@dataclass(frozen=True)
class KittiItem:
    """One KITTI pair to load: frames / cameras of ``open_dataset(root, **{key: name})``.

    ``reverse``: the pair is read the other way round (image b first, F^T), which gives temporal
    pairs t + k -> t and stereo pairs right -> left from the same files.
    """

    root: str
    key: str  # "sequence" or "drive"
    name: str
    frame: int
    kind: str
    step: int
    cams: tuple[int, int]
    reverse: bool = False

    @property
    def label(self) -> str:
        frame_b = self.frame + (self.step if self.kind == "temporal" else 0)
        arrow = "<-" if self.reverse else "->"
        return f"{self.name}/{self.kind}/f{self.frame}c{self.cams[0]}{arrow}f{frame_b}c{self.cams[1]}"


def kitti_pair_id(ds, item: KittiItem):
    """The :class:`fviz.data.pair.PairId` of an item (forward direction; ``reverse`` is applied by the caller)."""
    from fviz.data.pair import PairId

    frame_b = item.frame + (item.step if item.kind == "temporal" else 0)
    return PairId(ds.source, ds.name, item.kind, item.frame, frame_b, item.cams[0], item.cams[1], str(ds.root))


def load_kitti_pair(ds, item: KittiItem):
    """The :class:`fviz.data.pair.Pair` of an item (forward direction; ``reverse`` is applied by the caller)."""
    return ds.load(kitti_pair_id(ds, item))


class KittiPairs(torch.utils.data.Dataset):
    """KITTI pairs resized (and augmented) to the model input.  ds[list] -> batch (see module docstring).

    Augmentations draw from a generator seeded by the batch's indices and ``seed``, so a batch is the
    same whichever worker builds it.
    """

    def __init__(self, items: Sequence[KittiItem], input_hw: tuple[int, int], norm: str,
                 augment: Augment = Augment(), seed: int = 0, frame: tuple[float, ...] = ()):
        self.items = list(items)
        self.input_hw = (int(input_hw[0]), int(input_hw[1]))
        self.norm = norm
        self.frame = tuple(frame)  # the model's norm_frame: targets normalized where it normalizes
        self.augment = augment
        self.seed = int(seed)
        self._open: dict = {}
        self._images: dict[str, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.items)

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_open"] = {}
        state["_images"] = {}
        return state

    def _dataset(self, item: KittiItem):
        k = (item.root, item.key, item.name)
        if k not in self._open:
            from fviz.data.kitti import open_dataset

            self._open[k] = open_dataset(item.root, **{item.key: item.name})
        return self._open[k]

    def _gray(self, path) -> np.ndarray:
        """A frame's full-resolution gray image, decoded once per process (a frame is in many pairs:
        steps 1-3, both directions, stereo): (H, W) uint8.  ~0.47 MB a KITTI frame."""
        key = str(path)
        if key not in self._images:
            import cv2

            from fviz.data.kitti import read_image

            image = read_image(path)
            if len(self._images) >= MAX_CACHED_FRAMES:
                self._images.pop(next(iter(self._images)))
            self._images[key] = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
        return self._images[key]

    def load(self, i: int, rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(img_a (h, w), img_b (h, w), F (3, 3) normalized) as float32 numpy at the input size."""
        item = self.items[i]
        ds = self._dataset(item)
        pid = kitti_pair_id(ds, item)
        F = ds.ground_truth(pid)[4]
        image_a, image_b = (self._gray(ds.image_path(c, f)) for c, f in ((pid.cam_a, pid.frame_a), (pid.cam_b, pid.frame_b)))
        if image_a.shape != image_b.shape:
            raise FvizError(f"{item.label}: images of different sizes ({image_a.shape[1]}x{image_a.shape[0]} and "
                            f"{image_b.shape[1]}x{image_b.shape[0]})")
        if item.reverse:
            image_a, image_b, F = image_b, image_a, F.T
        aug = self.augment if rng is not None else Augment()
        a, b, F_small = augmented_pair(image_a, image_b, F, self.input_hw, aug, rng or np.random.default_rng(0))
        F_t = normalize_target(F_small, self.norm, item.label, self.frame)
        return a, b, F_t.astype(np.float32)

    def __getitem__(self, idx):
        indices = _as_indices(idx)
        rng = np.random.default_rng([self.seed, *indices]) if self.augment.active else None
        loaded = [self.load(i, rng) for i in indices]
        img_a = torch.from_numpy(np.stack([x[0] for x in loaded]))[:, None]
        img_b = torch.from_numpy(np.stack([x[1] for x in loaded]))[:, None]
        F = torch.from_numpy(np.stack([x[2] for x in loaded]))
        return img_a, img_b, F
