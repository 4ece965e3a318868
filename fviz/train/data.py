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
- :class:`KittiPairs`: KITTI pairs through :mod:`fviz.data.kitti` (``open_dataset`` and
  ``KittiSequence.load``), from one or several roots (``data.root`` + ``data.roots``), odometry
  sequences and raw drives, temporal pairs of several ``steps`` and stereo / cross-camera pairs of
  the ``cameras`` present (frames counted per camera folder: colour-only sequences work), gray or
  colour (converted to gray), optionally both directions.  The full-resolution images are cropped
  / resized / flipped (:class:`Augment`, every map exact: F' = A_b^-T F A_a^-1) to the input size;
  pairs whose ground truth disagrees with the images can be dropped (``data.max_gt_sed_px``,
  :func:`gt_agreement_px`).
- :class:`TensorPairs`: pairs already in memory (tests, benchmarks);
- :class:`CachedPairs` (``data.cache = true``): any of the above rendered / loaded once into
  memory as uint8, so that later epochs cost no rendering or PNG decoding.

Splits (:func:`make_datasets`): synthetic validation uses its own seeds, disjoint from training's;
KITTI validation uses the held-out ``data.val_sequences`` when given (a sequence cannot be both), else
the last ``val_fraction`` of each training sequence's pairs (a contiguous block, so that validation
frames are not neighbours of training frames except at one boundary).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from fviz.errors import FvizError
from fviz.geometry.fundamental import NormalizationError, normalize
from fviz.train.augment import Augment, augmented_pair
from fviz.train.recipe import synthetic_api, resolve_path, scene_config  # noqa: F401 (scene_config: re-exported)

MAX_CACHED_FRAMES = 4000  # decoded KITTI frames kept per process (~1.9 GB at 1242 x 375)
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


# ----------------------------------------------------------------------------------------------- augmentation


def frames_of(ds, cam: int) -> set[int]:
    """Frame numbers with an image of camera ``cam`` (counted in its folder: colour-only sequences have no image_0)."""
    d = ds.image_dirs.get(cam)
    if d is None or not d.is_dir():
        return set()
    return {int(p.stem) for p in d.glob("*.png") if p.stem.isdigit()}


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
                 augment: Augment = Augment(), seed: int = 0):
        self.items = list(items)
        self.input_hw = (int(input_hw[0]), int(input_hw[1]))
        self.norm = norm
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
        F_t = normalize_target(F_small, self.norm, item.label)
        return a, b, F_t.astype(np.float32)

    def __getitem__(self, idx):
        indices = _as_indices(idx)
        rng = np.random.default_rng([self.seed, *indices]) if self.augment.active else None
        loaded = [self.load(i, rng) for i in indices]
        img_a = torch.from_numpy(np.stack([x[0] for x in loaded]))[:, None]
        img_b = torch.from_numpy(np.stack([x[1] for x in loaded]))[:, None]
        F = torch.from_numpy(np.stack([x[2] for x in loaded]))
        return img_a, img_b, F


def gt_agreement_px(pair, features=None) -> float:
    """How well a pair's ground truth agrees with its images: median SED (px) of the SIFT + MAGSAC++ inliers
    to F_gt (NaN with fewer than 16 inliers).  The sample data's README: 0.1-0.9 px when the poses are good.
    ``features``: a :class:`fviz.estimators.features.FeatureCache` shared across pairs (a frame is detected once)."""
    import cv2

    from fviz.estimators.features import FeatureCache, FeatureConfig, match
    from fviz.geometry import symmetric_epipolar_distance

    features = features or FeatureCache(FeatureConfig(), threads=1)
    fa, fb = features.get_pair(pair.id.key_a, pair.image_a, pair.id.key_b, pair.image_b)
    m = match(fa, fb, features.cfg)
    if len(m) < 16:
        return float("nan")
    _, mask = cv2.findFundamentalMat(m.x_a, m.x_b, cv2.USAC_MAGSAC, 1.0, 0.999, 10000)
    if mask is None or mask.sum() < 16:
        return float("nan")
    inl = mask.ravel().astype(bool)
    return float(np.median(symmetric_epipolar_distance(pair.F_gt, m.x_a[inl], m.x_b[inl])))


# ----------------------------------------------------------------------------------------------- splits


def synthetic_seeds(seed: int, train_size: int, val_size: int) -> tuple[range, range]:
    """Disjoint training and validation seeds of a recipe seed (validation counts down from the top)."""
    if train_size + val_size > SEED_SPAN:
        raise FvizError(f"data.train_size + data.val_size must be at most {SEED_SPAN}")
    base = 1 + (int(seed) % 100) * SEED_SPAN
    return range(base, base + train_size), range(base + SEED_SPAN - val_size, base + SEED_SPAN)


def _open_named(roots: list[str], name: str):
    """(key, dataset) of a sequence ("00") or drive ("2011_09_26_drive_0001") from the first root holding it."""
    from fviz.data.kitti import open_dataset

    key = "drive" if "_drive_" in name else "sequence"
    errors = []
    for root in roots:
        try:
            return key, open_dataset(root, **{key: name})
        except FvizError as exc:
            errors.append(str(exc))
    raise FvizError(f"data: {key} {name!r} is in none of the roots {roots} ({errors[-1] if errors else 'no root given'})")


def _camera_pairs(recipe, kind: str, available: list[int]) -> list[tuple[int, int]]:
    """(cam_a, cam_b) of a pair kind: temporal pairs use one camera, stereo pairs two different ones."""
    cams = [c for c in (recipe.data.cameras or sorted(set(recipe.cams))) if c in available]
    if kind == "temporal":
        return [(c, c) for c in cams]
    if not recipe.data.cameras:
        return [recipe.cams] if set(recipe.cams) <= set(available) else []
    return [(a, b) for a in cams for b in cams if a < b]


PAPER_SPLIT = {"train": (0.0, 0.8), "val": (0.8, 0.9), "test": (0.9, 1.0)}  # the paper's 1600 / 200 / 200


def paper_split_frames(name: str, frames: Sequence[int], part: str) -> set[int]:
    """The paper's split (random frames of the same drives, 80 / 10 / 10 %): the frames of ``part``
    ("train", "val" or "test") of one sequence or drive, from a permutation seeded by its name (so
    every camera pair and every run draws the same frames)."""
    import zlib

    order = sorted(frames)
    perm = np.random.default_rng(zlib.crc32(name.encode())).permutation(len(order))
    lo, hi = PAPER_SPLIT[part]
    return {order[i] for i in perm[int(round(lo * len(order))) : int(round(hi * len(order)))]}


def kitti_items(recipe, name: str, part: str | None = None) -> list[KittiItem]:
    """Every pair of one sequence / drive the recipe selects (kinds, cameras, steps, directions, frames);
    ``part``: only pairs whose first frame is in that part of the paper's split (:func:`paper_split_frames`,
    drawn from the frames of camera 0, or the first camera present)."""
    d = recipe.data
    roots = [str(resolve_root(r)) for r in [d.root, *d.roots] if r]
    key, ds = _open_named(roots, name)
    items: list[KittiItem] = []
    if part is not None:
        in_part = paper_split_frames(name, set().union(*(frames_of(ds, c) for c in ds.projections)), part)
    for kind in recipe.kinds:
        for cams in _camera_pairs(recipe, kind, sorted(ds.projections)):
            frames = frames_of(ds, cams[0]) & frames_of(ds, cams[1])
            if kind == "temporal":
                frames &= ds.pose_frames  # both frames need a pose (raw drives: an oxts packet)
            firsts = frames & in_part if part is not None else frames
            lo, hi = (d.frames[0], d.frames[1]) if d.frames else (0, 1 << 30)
            steps = d.steps if kind == "temporal" else [0]
            for f in sorted(firsts):
                if not lo <= f < hi or (f - lo) % d.frame_stride:
                    continue
                for step in steps:
                    if f + step not in frames or f + step >= hi:
                        continue
                    for reverse in (False, True) if d.both_directions else (False,):
                        items.append(KittiItem(str(ds.root), key, name, f, kind, int(step), tuple(cams), reverse))
    if not items:
        raise FvizError(f"data: {key} {name!r} gives no {'/'.join(recipe.kinds)} pairs with cameras "
                        f"{d.cameras or list(recipe.cams)}, steps {list(d.steps)}, frames {d.frames or 'all'}")
    return items


def resolve_root(root: str):
    return resolve_path(root)


def filter_by_gt_agreement(items: list[KittiItem], max_sed_px: float, cache_path=None, on_item=None
                           ) -> tuple[list[KittiItem], dict[str, float]]:
    """Items whose ground truth agrees with their images (:func:`gt_agreement_px` <= ``max_sed_px``).

    The figure depends only on the images (not the direction): one per unordered pair, cached in
    ``cache_path`` (JSON, by label) when given.  Returns (kept items, {label: px}).
    """
    import json

    cache: dict[str, float] = {}
    if cache_path is not None and Path(cache_path).is_file():
        try:
            cache = {k: float(v) for k, v in json.loads(Path(cache_path).read_text()).items()}
        except (ValueError, TypeError, AttributeError):
            cache = {}
    opened: dict = {}
    kept = []
    from fviz.estimators.features import FeatureCache, FeatureConfig

    features = FeatureCache(FeatureConfig(), threads=1)  # items are in frame order: neighbours share frames
    try:
        for n, item in enumerate(items):
            fwd = KittiItem(**{**item.__dict__, "reverse": False})
            if fwd.label not in cache:
                k = (fwd.root, fwd.key, fwd.name)
                if k not in opened:
                    from fviz.data.kitti import open_dataset

                    opened[k] = open_dataset(fwd.root, **{fwd.key: fwd.name})
                cache[fwd.label] = gt_agreement_px(load_kitti_pair(opened[k], fwd), features)
            if cache[fwd.label] <= max_sed_px:  # NaN (too few matches to tell) is dropped too
                kept.append(item)
            if on_item is not None:
                on_item(n + 1, len(items))
    finally:  # what was measured is kept, also on Ctrl-C
        if cache_path is not None and cache:
            from fviz.atomic import write_text

            Path(cache_path).parent.mkdir(parents=True, exist_ok=True)
            write_text(cache_path, json.dumps(cache, indent=0, sort_keys=True))
    return kept, cache


def make_datasets(recipe, render_device: str | torch.device = "cpu") -> tuple[torch.utils.data.Dataset, torch.utils.data.Dataset]:
    """(train, val) datasets of a recipe.  Raises FvizError for a recipe that cannot give data."""
    d = recipe.data
    hw, norm = recipe.input_hw, recipe.model.variant.rsplit("-", 1)[1]
    if d.source == "synthetic":
        synthetic_api()
        scene_config(hw, d.synthetic)  # fail early on unknown SceneConfig fields
        tr, va = synthetic_seeds(recipe.train.seed, d.train_size, d.val_size)
        return (SyntheticPairs(tr, hw, norm, d.synthetic, render_device), SyntheticPairs(va, hw, norm, d.synthetic, render_device))
    if norm == "etr" and "stereo" in recipe.kinds:
        raise FvizError(
            f"{recipe.model.variant}: ETR normalization is undefined for rectified stereo pairs (F33 = 0); "
            "train an fbn or abs variant on them, or use temporal pairs"
        )
    if not d.root and not d.roots:
        raise FvizError(f"data.root must name the KITTI dataset root for data.source {d.source!r}")
    names = [*d.sequences, *d.drives]
    if not names:
        raise FvizError("data.sequences and data.drives are empty: name at least one sequence or drive to train on")
    held_out = set(d.val_sequences) & set(names)
    if held_out:
        raise FvizError(f"data.val_sequences {sorted(held_out)} are also training sequences: a held-out sequence must not be trained on")
    train_items: list[KittiItem] = []
    val_items: list[KittiItem] = []
    if d.split == "paper" and d.val_sequences:
        raise FvizError("data.split = 'paper' draws validation frames from the training drives: leave data.val_sequences empty")
    for name in names if d.split == "paper" else ():
        train_items += kitti_items(recipe, name, "train")
        val_items += kitti_items(recipe, name, "val")
    for name in names if d.split != "paper" else ():
        items = kitti_items(recipe, name)
        n_val = 0 if d.val_sequences else int(round(len(items) * d.val_fraction))
        if d.val_fraction > 0 and not d.val_sequences and len(items) > 1:
            n_val = max(n_val, 1)
        train_items += items[: len(items) - n_val]
        val_items += items[len(items) - n_val :]
    for name in d.val_sequences:
        val_items += kitti_items(recipe, name)
    if d.max_gt_sed_px > 0:
        cache = resolve_root(recipe.train.out_dir.replace("{variant}", recipe.model.variant)) / "gt_agreement.json"
        train_items, _ = filter_by_gt_agreement(train_items, d.max_gt_sed_px, cache)
    if d.val_size and len(val_items) > d.val_size:  # evenly spread subset
        keep = np.linspace(0, len(val_items) - 1, d.val_size).round().astype(int)
        val_items = [val_items[i] for i in keep]
    if not train_items:
        raise FvizError("data: no training pairs left after the validation split"
                        + (" and the ground-truth filter" if d.max_gt_sed_px else ""))
    augment = Augment(d.augment_swap, d.augment_flip, d.augment_crop, d.augment_photometric)
    return KittiPairs(train_items, hw, norm, augment, recipe.train.seed), KittiPairs(val_items, hw, norm)


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
