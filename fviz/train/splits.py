"""Which pairs a recipe trains and validates on: :func:`make_datasets` -> (train, val) datasets of
:mod:`fviz.train.data`.

Splits: synthetic validation uses its own seeds, disjoint from training's (:func:`synthetic_seeds`); KITTI
validation uses the held-out ``data.val_sequences`` when given (a sequence cannot be both), else the last
``val_fraction`` of each training sequence's pairs (a contiguous block, so that validation frames are not
neighbours of training frames except at one boundary), or the paper's random 80 / 10 / 10 % of frames
(``data.split = "paper"``, :func:`paper_split_frames`).  :func:`kitti_items` lists a sequence's pairs (kinds,
cameras, steps, directions, frames); :func:`filter_by_gt_agreement` drops pairs whose ground truth disagrees with
their images (``data.max_gt_sed_px``, :func:`gt_agreement_px`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from fviz.errors import FvizError
from fviz.train.augment import Augment
from fviz.train.data import KittiItem, KittiPairs, SyntheticPairs, load_kitti_pair
from fviz.train.recipe import resolve_path, scene_config, synthetic_api

SEED_SPAN = 10**7  # synthetic seeds of one recipe seed: [base, base + SEED_SPAN)


def synthetic_seeds(seed: int, train_size: int, val_size: int) -> tuple[range, range]:
    """Disjoint training and validation seeds of a recipe seed (validation counts down from the top)."""
    if train_size + val_size > SEED_SPAN:
        raise FvizError(f"data.train_size + data.val_size must be at most {SEED_SPAN}")
    base = 1 + (int(seed) % 100) * SEED_SPAN
    return range(base, base + train_size), range(base + SEED_SPAN - val_size, base + SEED_SPAN)


def open_named(roots: list[str], name: str):
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
    key, ds = open_named(roots, name)
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


def frames_of(ds, cam: int) -> set[int]:
    """Frame numbers with an image of camera ``cam`` (counted in its folder: colour-only sequences have no image_0)."""
    d = ds.image_dirs.get(cam)
    if d is None or not d.is_dir():
        return set()
    return {int(p.stem) for p in d.glob("*.png") if p.stem.isdigit()}


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


def make_datasets(recipe, render_device: str | torch.device = "cpu") -> tuple[torch.utils.data.Dataset, torch.utils.data.Dataset]:
    """(train, val) datasets of a recipe.  Raises FvizError for a recipe that cannot give data."""
    d = recipe.data
    hw, norm = recipe.input_hw, recipe.model.variant.rsplit("-", 1)[1]
    if d.source == "synthetic":
        synthetic_api()
        scene_config(hw, d.synthetic)  # fail early on unknown SceneConfig fields
        tr, va = synthetic_seeds(recipe.train.seed, d.train_size, d.val_size)
        return (SyntheticPairs(tr, hw, norm, d.synthetic, render_device), SyntheticPairs(va, hw, norm, d.synthetic, render_device))
    frame = unrectified_frame(recipe) if recipe.model.norm_frame == "unrectified" else ()
    if norm == "etr" and "stereo" in recipe.kinds and not frame:
        raise FvizError(
            f"{recipe.model.variant}: ETR normalization is undefined for rectified stereo pairs (F33 = 0); "
            "train an fbn or abs variant on them, use temporal pairs, or (raw drives) set model.norm_frame = 'unrectified'"
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
    return KittiPairs(train_items, hw, norm, augment, recipe.train.seed, frame), KittiPairs(val_items, hw, norm, frame=frame)


def network_config(recipe):
    """The :class:`fviz.models.FNetConfig` a recipe trains, its ``norm_frame`` read from the drives' calibration."""
    return recipe.fnet_config(unrectified_frame(recipe) if recipe.model.norm_frame == "unrectified" else ())


def unrectified_frame(recipe) -> tuple[float, ...]:
    """``model.norm_frame = "unrectified"``: the frame the network normalizes F in (``FNetConfig.norm_frame``), 18
    floats, U_a then U_b row-major: rectified model-input pixels -> the unrectified cameras' pixels at the input's
    scale, U = S_u H S_r^-1 (H of :func:`fviz.data.kitti.raw_cameras`, S the resize of each image to the input).
    There a rectified stereo pair's F33 is most of ||F|| (the cameras' principal points differ by ~12 px in y), so ETR
    is defined: the paper's ground-truth frame. Pairs read the other way (b -> a) keep the same U's: F^T there is
    ~ -F, still well away from F33 = 0. Every drive must share one calibration."""
    from fviz.data.kitti import raw_cameras
    from fviz.models.predict import scale_matrix

    d = recipe.data
    if d.source != "kitti-raw" or recipe.kinds != ["stereo"]:
        raise FvizError("model.norm_frame = 'unrectified' needs data.source = 'kitti-raw' and stereo pairs only "
                        f"(data.kinds = ['stereo']), got {d.source!r} and {recipe.kinds}")
    cams = list(d.cameras or recipe.cams)
    if len(cams) != 2:
        raise FvizError(f"model.norm_frame = 'unrectified' needs two cameras (data.cameras), got {cams}")
    roots = [str(resolve_root(r)) for r in [d.root, *d.roots] if r]
    wh = (recipe.input_hw[1], recipe.input_hw[0])
    frames = {}
    for name in [*d.drives, *d.val_sequences]:
        _, ds = open_named(roots, name)
        cameras = raw_cameras(ds.calib_path)
        missing = [c for c in cams if c not in cameras]
        if missing:
            raise FvizError(f"{ds.calib_path}: no unrectified camera {missing[0]} (K_0{missing[0]}) for model.norm_frame")
        U = [scale_matrix(cameras[c].size, wh) @ cameras[c].H @ np.linalg.inv(scale_matrix(cameras[c].rect_size, wh)) for c in cams]
        frames[name] = np.concatenate([u.ravel() for u in U])
    first_name, first = next(iter(frames.items()))
    other = [n for n, f in frames.items() if not np.allclose(f, first, rtol=1e-9, atol=1e-12)]
    if other:
        raise FvizError(f"model.norm_frame = 'unrectified': {', '.join(other)} have another calibration than {first_name}; "
                        "train drives of one calibration (one date) together")
    return tuple(float(v) for v in first)
