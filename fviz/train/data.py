"""Training data: (img_a, img_b, F_target) at the model's input size.

Every dataset here is indexed by a *list* of indices and returns a whole batch

    ds[[i, j, ...]] -> img_a (B, 1, H, W) float32 in [0, 1], img_b (B, 1, H, W), F (B, 3, 3) float32

with F in pixel coordinates of the (H, W) model input (``x_b^T F x_a = 0``), normalized with the
model's norm (etr / fbn / abs, :func:`fviz.geometry.normalize`).  The loop feeds lists of indices
through a ``DataLoader(batch_size=None)``, so workers build whole batches.

- :class:`SyntheticPairs`: scenes from :func:`fviz.data.synthetic.render_batch`, one seed per index,
  rendered directly at the input size (no resize: its F is already in input pixels).  With
  ``num_workers = 0`` batches are rendered in the main process on the training device (GPU
  rendering); with workers, on the CPU in the workers.
- :class:`KittiPairs`: KITTI odometry temporal pairs or KITTI raw stereo pairs through
  :func:`fviz.data.kitti.open_dataset`; the full-resolution images are resized (gray, INTER_AREA)
  and the ground-truth F mapped to input pixels by F_small = S_b^-T F_full S_a^-1, the inverse of
  what :func:`fviz.models.predict_F` does.
- :class:`TensorPairs`: pairs already in memory (tests, benchmarks);
- :class:`CachedPairs` (``data.cache = true``): any of the above rendered / loaded once into
  memory as uint8, so that later epochs cost no rendering or PNG decoding.

Splits (:func:`make_datasets`): synthetic validation uses its own seeds, disjoint from training's;
KITTI validation uses ``data.val_sequences`` when given, else the last ``val_fraction`` of each
training sequence's frames (a contiguous block, so that validation frames are not neighbours of
training frames except at one boundary).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from fviz.errors import FvizError
from fviz.geometry.fundamental import NormalizationError, normalize

SEED_SPAN = 10**7  # synthetic seeds of one recipe seed: [base, base + SEED_SPAN)


def normalize_target(F: np.ndarray, norm: str, what: str) -> np.ndarray:
    """numpy normalize with a message naming the pair when ETR is undefined."""
    try:
        return normalize(F, norm)
    except NormalizationError:
        raise FvizError(
            f"{what}: ETR normalization is undefined for its ground-truth F (F33 ~ 0, e.g. rectified stereo); "
            "train an fbn or abs variant on these pairs, or use temporal pairs"
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


def _synthetic_api():
    try:
        from fviz.data import synthetic
    except ImportError as exc:
        raise FvizError(f"data.source 'synthetic' needs fviz.data.synthetic, which cannot be imported: {exc}") from None
    return synthetic


def scene_config(input_hw: tuple[int, int], extra: dict):
    """SceneConfig(width=W, height=H, **extra), unknown fields reported as FvizError."""
    synthetic = _synthetic_api()
    if "width" in extra or "height" in extra:
        raise FvizError("data.synthetic: width/height come from model.input_size; do not set them here")
    try:
        return synthetic.SceneConfig(width=int(input_hw[1]), height=int(input_hw[0]), **extra)
    except TypeError as exc:
        raise FvizError(f"data.synthetic: {exc}") from None


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

        synthetic = _synthetic_api()
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
    """One KITTI pair to load: ``open_dataset(root, **{key: name}).pair(frame, kind, step, cams)``."""

    root: str
    key: str  # "sequence" or "drive"
    name: str
    frame: int
    kind: str
    step: int
    cams: tuple[int, int]


class KittiPairs(torch.utils.data.Dataset):
    """KITTI pairs resized to the model input.  ds[list] -> batch (see module docstring)."""

    def __init__(self, items: Sequence[KittiItem], input_hw: tuple[int, int], norm: str):
        self.items = list(items)
        self.input_hw = (int(input_hw[0]), int(input_hw[1]))
        self.norm = norm
        self._open: dict = {}

    def __len__(self) -> int:
        return len(self.items)

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_open"] = {}
        return state

    def _dataset(self, item: KittiItem):
        k = (item.root, item.key, item.name)
        if k not in self._open:
            from fviz.data.kitti import open_dataset

            self._open[k] = open_dataset(item.root, **{item.key: item.name})
        return self._open[k]

    def load(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(img_a (H, W), img_b (H, W), F (3, 3)) as float32 numpy at the input size."""
        from fviz.models.predict import f_to_input, to_model_input

        item = self.items[i]
        if item.kind == "temporal":
            pair = self._dataset(item).pair(item.frame, kind="temporal", step=item.step, cams=item.cams)
        else:
            pair = self._dataset(item).pair(item.frame, kind="stereo", cams=item.cams)
        F_small = f_to_input(pair.F_gt, pair.size_a, pair.size_b, self.input_hw)
        F_t = normalize_target(F_small, self.norm, pair.id.name)
        return to_model_input(pair.image_a, self.input_hw), to_model_input(pair.image_b, self.input_hw), F_t.astype(np.float32)

    def __getitem__(self, idx):
        loaded = [self.load(i) for i in _as_indices(idx)]
        img_a = torch.from_numpy(np.stack([x[0] for x in loaded]))[:, None]
        img_b = torch.from_numpy(np.stack([x[1] for x in loaded]))[:, None]
        F = torch.from_numpy(np.stack([x[2] for x in loaded]))
        return img_a, img_b, F


# ----------------------------------------------------------------------------------------------- splits


def synthetic_seeds(seed: int, train_size: int, val_size: int) -> tuple[range, range]:
    """Disjoint training and validation seeds of a recipe seed (validation counts down from the top)."""
    if train_size + val_size > SEED_SPAN:
        raise FvizError(f"data.train_size + data.val_size must be at most {SEED_SPAN}")
    base = 1 + (int(seed) % 100) * SEED_SPAN
    return range(base, base + train_size), range(base + SEED_SPAN - val_size, base + SEED_SPAN)


def _kitti_items(recipe, names: list[str], for_val: bool) -> tuple[list[KittiItem], list[KittiItem]]:
    """(train items, val items) of these sequences/drives; val from the tail when not ``for_val``."""
    from fviz.data.kitti import open_dataset
    from fviz.train.recipe import resolve_path

    d = recipe.data
    key = "sequence" if d.source == "kitti-odometry" else "drive"
    root = str(resolve_path(d.root))
    kind, cams = recipe.kind, recipe.cams
    train_items: list[KittiItem] = []
    val_items: list[KittiItem] = []
    for name in names:
        ds = open_dataset(root, **{key: name})
        n = int(ds.num_frames)
        start, stop = (d.frames[0], min(d.frames[1], n)) if d.frames else (0, n)
        steps = d.steps if kind == "temporal" else [0]
        items = [
            KittiItem(root, key, name, f, kind, int(step), cams)
            for f in range(start, stop, d.frame_stride)
            for step in steps
            if f + step < stop
        ]
        if not items:
            raise FvizError(f"data: {key} {name!r} gives no {kind} pairs (frames {start}..{stop}, steps {list(steps)})")
        if for_val:
            val_items += items
            continue
        n_val = 0 if d.val_sequences else int(round(len(items) * d.val_fraction))
        if d.val_fraction > 0 and not d.val_sequences and len(items) > 1:
            n_val = max(n_val, 1)
        train_items += items[: len(items) - n_val]
        val_items += items[len(items) - n_val :]
    return train_items, val_items


def make_datasets(recipe, render_device: str | torch.device = "cpu") -> tuple[torch.utils.data.Dataset, torch.utils.data.Dataset]:
    """(train, val) datasets of a recipe.  Raises FvizError for a recipe that cannot give data."""
    d = recipe.data
    hw, norm = recipe.input_hw, recipe.model.variant.rsplit("-", 1)[1]
    if d.source == "synthetic":
        _synthetic_api()
        scene_config(hw, d.synthetic)  # fail early on unknown SceneConfig fields
        tr, va = synthetic_seeds(recipe.train.seed, d.train_size, d.val_size)
        return (SyntheticPairs(tr, hw, norm, d.synthetic, render_device), SyntheticPairs(va, hw, norm, d.synthetic, render_device))
    if norm == "etr" and recipe.kind == "stereo":
        raise FvizError(
            f"{recipe.model.variant}: ETR normalization is undefined for rectified stereo pairs (F33 = 0); "
            "train an fbn or abs variant on them, or use temporal pairs"
        )
    try:
        import fviz.data.kitti  # noqa: F401
    except ImportError as exc:
        raise FvizError(f"data.source {d.source!r} needs fviz.data.kitti, which cannot be imported: {exc}") from None
    if not d.root:
        raise FvizError(f"data.root must name the KITTI dataset root for data.source {d.source!r}")
    names = d.sequences if d.source == "kitti-odometry" else d.drives
    if not names:
        what = "data.sequences" if d.source == "kitti-odometry" else "data.drives"
        raise FvizError(f"{what} is empty: name at least one {'sequence' if d.source == 'kitti-odometry' else 'drive'} to train on")
    train_items, val_items = _kitti_items(recipe, list(names), for_val=False)
    if d.val_sequences:
        val_items = _kitti_items(recipe, list(d.val_sequences), for_val=True)[1]
    if d.val_size and len(val_items) > d.val_size:  # evenly spread subset
        keep = np.linspace(0, len(val_items) - 1, d.val_size).round().astype(int)
        val_items = [val_items[i] for i in keep]
    if not train_items:
        raise FvizError("data: no training pairs left after the validation split")
    return KittiPairs(train_items, hw, norm), KittiPairs(val_items, hw, norm)


def epoch_batches(n: int, batch_size: int, seed: int, epoch: int, rank: int = 0, world: int = 1, shuffle: bool = True) -> list[list[int]]:
    """The batches (lists of indices) of one epoch: a seeded permutation, split across ranks, full batches only."""
    if shuffle:
        g = torch.Generator().manual_seed(int(seed) * 100_003 + int(epoch))
        order = torch.randperm(n, generator=g).tolist()
    else:
        order = list(range(n))
    order = order[rank::world][: n // world]  # the same number of batches on every rank
    nb = len(order) // batch_size if shuffle else math.ceil(len(order) / batch_size)
    if shuffle and nb == 0 and order:  # fewer pairs than one batch: one smaller batch
        return [order]
    return [order[i * batch_size : (i + 1) * batch_size] for i in range(nb)]
