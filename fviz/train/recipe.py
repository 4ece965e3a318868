"""Training recipes: TOML -> a typed, validated :class:`Recipe`.

A recipe has three tables, every key optional (defaults below):

    base = "kitti_base.toml"        # optional: inherit another recipe (path relative to this file)
    description = "..."             # optional free text

    [model]   variant, input_size, width, pool_grid, hidden, dropout, conditioned, norm_frame
    [data]    source, root, sequences, drives, val_sequences, kind, steps, cams, frames, frame_stride,
              val_fraction, train_size, val_size, val_points, cache, synthetic = { SceneConfig fields }
    [train]   batch_size, lr, schedule, warmup_steps, weight_decay, epochs, max_steps, l1_weight, l2_weight, loss_frame,
              grad_clip, t_norm_weight, sed_weight, sed_points, keep_best, seed, device, amp, num_workers, threads,
              out_dir, init, checkpoint_every, val_every, log_every, watch_pairs, watch_every, export_dtype

    [variants."siamese-rec-pos-fbn"]   # optional per-variant overrides, applied when
    train = { lr = 3e-4 }              # model.variant is that name

Layers, lowest first: the ``base`` chain, the recipe file, its ``[variants.<model.variant>]`` table,
then the command line's ``--set key=value`` overrides (dotted keys, the value parsed as a TOML scalar
or array; a bare word is taken as a string: ``--set model.variant=single-epi-abs``).  A table in a
later layer is merged key by key into the earlier one.  The variant used to pick the
``[variants.X]`` table is the final one (``--set model.variant=...`` included), so one base recipe
serves all 36 variants: ``fviz train recipes/kitti_base.toml --set model.variant=single-epi-abs``.

Every layer is checked on its own: an unknown key or a value of the wrong type raises FvizError
naming the file (or the ``--set`` argument) and the key, e.g.
``recipe recipes/x.toml: unknown key 'model.hed'``.

``train.init`` starts a fresh run from another model's weights (synthetic pretraining, then KITTI
fine-tuning: ``recipes/kitti_finetune.toml``); the model section must describe the same network.

Relative paths in ``data.root``, ``data.roots``, ``train.out_dir`` and ``train.init`` are relative to the working directory
(``~`` and ``$VARS`` are expanded; ``{variant}`` in ``train.out_dir`` becomes the variant's name);
``base`` is relative to the recipe that names it.
"""

from __future__ import annotations

import copy
import math
import os
import sys
import typing
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from fviz.errors import FvizError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SOURCES = ("synthetic", "kitti-odometry", "kitti-raw")


def _choices(*values: str) -> dict:
    return {"choices": values}


@dataclass
class ModelSection:
    """Which network (see :mod:`fviz.models.model`)."""

    variant: str = "siamese-rec-pos-fbn"
    input_size: list[int] = field(default_factory=lambda: [96, 320], metadata={"len": 2, "min": 8})  # (H, W)
    width: int = field(default=128, metadata={"min": 1})
    pool_grid: list[int] = field(default_factory=lambda: [3, 10], metadata={"len": 2, "min": 1})  # (rows, cols)
    hidden: int = field(default=256, metadata={"min": 1})
    dropout: float = field(default=0.5, metadata={"min": 0.0, "max": 0.99})
    conditioned: bool = True
    # Where the norm layer (and the targets) normalize F: "input", the model input's pixels; "unrectified", a raw
    # drive's unrectified cameras (stereo only), where ETR is defined (fviz.train.splits.unrectified_frame).
    norm_frame: str = field(default="input", metadata=_choices("input", "unrectified"))


@dataclass
class DataSection:
    """Where pairs come from.  Synthetic: seeds; KITTI: sequences/drives and frames."""

    source: str = field(default="synthetic", metadata=_choices(*SOURCES))
    root: str = ""  # KITTI dataset root (as fviz.data.kitti.open_dataset takes it)
    sequences: list[str] = field(default_factory=list)  # kitti-odometry training sequences, e.g. ["00", "01"]
    drives: list[str] = field(default_factory=list)  # kitti-raw training drives, e.g. ["2011_09_26_drive_0001"]
    val_sequences: list[str] = field(default_factory=list)  # held-out sequences/drives; empty: val_fraction
    kind: str = field(default="", metadata=_choices("", "temporal", "stereo"))  # "": temporal (odometry) / stereo (raw)
    steps: list[int] = field(default_factory=lambda: [1], metadata={"min": 1})  # temporal frame gaps
    cams: list[int] = field(default_factory=list, metadata={"len": 2, "min": 0, "allow_empty": True})  # default (0,0)/(0,1)
    frames: list[int] = field(default_factory=list, metadata={"len": 2, "min": 0, "allow_empty": True})  # [start, stop)
    frame_stride: int = field(default=1, metadata={"min": 1})
    val_fraction: float = field(default=0.1, metadata={"min": 0.0, "max": 0.9})
    train_size: int = field(default=20000, metadata={"min": 1})  # synthetic: distinct training scenes per epoch
    val_size: int = field(default=256, metadata={"min": 0})  # synthetic: validation scenes; KITTI: cap (0 = all)
    val_points: int = field(default=256, metadata={"min": 8})  # points per pair for EPI-ABS / EPI-SQR
    cache: bool = False  # render / load every pair once into memory (uint8), then train epochs from there
    synthetic: dict = field(default_factory=dict)  # extra fviz.data.synthetic.SceneConfig fields
    # KITTI, several roots and pair kinds (see fviz/train/data.py):
    roots: list[str] = field(default_factory=list)  # more dataset roots; a sequence/drive comes from the first root holding it
    kinds: list[str] = field(default_factory=list, metadata=_choices("temporal", "stereo"))  # overrides kind when given
    cameras: list[int] = field(default_factory=list, metadata={"min": 0, "max": 3})  # cameras to pair (empty: cams)
    both_directions: bool = False  # temporal t -> t+k and t+k -> t; stereo a -> b and b -> a
    # "paper": the paper's split, random frames of the same sequences / drives, 80 % train, 10 % validation
    # (10 % test, never loaded here: fviz.train.splits.paper_split_frames); "": val_sequences or val_fraction
    split: str = field(default="", metadata=_choices("", "paper"))
    max_gt_sed_px: float = field(default=0.0, metadata={"min": 0.0})  # > 0: drop pairs whose GT disagrees with the images
    augment_swap: float = field(default=0.0, metadata={"min": 0.0, "max": 1.0})  # probability: a <-> b, F -> F^T
    augment_flip: float = field(default=0.0, metadata={"min": 0.0, "max": 1.0})  # probability: both mirrored
    augment_crop: float = field(default=0.0, metadata={"min": 0.0, "max": 0.5})  # up to this fraction cut (scale + shift)
    augment_photometric: float = field(default=0.0, metadata={"min": 0.0, "max": 1.0})  # gain / gamma / noise strength


@dataclass
class TrainSection:
    """Optimization, device and output."""

    batch_size: int = field(default=32, metadata={"min": 1})  # per process (per GPU under torchrun)
    lr: float = field(default=1e-4, metadata={"min": 0.0})
    schedule: str = field(default="constant", metadata=_choices("constant", "cosine"))  # cosine: lr -> 0 at the last step
    warmup_steps: int = field(default=0, metadata={"min": 0})  # linear warm-up from 0
    weight_decay: float = field(default=0.0, metadata={"min": 0.0})
    epochs: int = field(default=10, metadata={"min": 1})
    max_steps: int = field(default=0, metadata={"min": 0})  # > 0: stop after this many optimizer steps
    l1_weight: float = field(default=1.0, metadata={"min": 0.0})
    l2_weight: float = field(default=1.0, metadata={"min": 0.0})
    loss_frame: str = field(default="conditioned", metadata=_choices("conditioned", "pixel"))
    grad_clip: float = field(default=1.0, metadata={"min": 0.0})  # max gradient norm (0: off)
    # REC heads: keep the raw translation near unit length (fviz/models/heads.py): the t outputs of the
    # starting weights are rescaled to median length 1 before the first step, and the loss adds
    # t_norm_weight * mean(log ||raw t||)^2.  0 turns both off (the parametrisation before 2026-12).
    t_norm_weight: float = field(default=0.01, metadata={"min": 0.0})
    # A geometric term beside the F loss: sed_weight * mean robust symmetric epipolar distance (model-input px,
    # Charbonnier with a 1 px knee) of the prediction on sed_points virtual correspondences of the target per pair
    # (fviz.train.losses.sed_loss).  It weighs a pair's error as the images show it: a 1 deg yaw moves points
    # by f * 0.017 px, which L1 + L2 on a unit-norm F barely sees.  0: the paper's loss alone.
    sed_weight: float = field(default=0.0, metadata={"min": 0.0})
    sed_points: int = field(default=64, metadata={"min": 8})
    # A validation figure (e.g. "sed_px"; lower is better): each validation that improves it exports
    # out_dir/best.pt (early stopping without losing the last checkpoint).  "": off.
    keep_best: str = field(default="", metadata=_choices("", "loss", "epi_abs", "epi_sqr", "sed_px", "f_dist"))
    seed: int = 0
    device: str = "auto"  # auto | cpu | cuda | cuda:N
    amp: str = field(default="auto", metadata=_choices("auto", "bf16", "fp16", "off"))
    num_workers: int = field(default=2, metadata={"min": 0})
    # CPU threads of torch in this process (0: torch's default, one per core).  1 by default: the small
    # CPU recipe ran 6x faster with 1 thread than with torch's default on a shared 2-core machine
    # (OpenMP threads waiting on each other); GPU training does not depend on it.
    threads: int = field(default=1, metadata={"min": 0})
    out_dir: str = "runs/fviz"
    init: str = ""  # a model file (checkpoint or weights) whose weights start a fresh run: fine-tuning
    checkpoint_every: int = field(default=0, metadata={"min": 0})  # steps; 0: at each validation
    val_every: int = field(default=0, metadata={"min": 0})  # steps; 0: at the end of each epoch
    log_every: int = field(default=10, metadata={"min": 1})
    # train.rrd shows the network on a few fixed validation pairs (fviz.log_training_step): its epipolar lines beside
    # the ground truth's, its epipole and residuals, on the ``step`` timeline (scrub it: the lines converge).
    watch_pairs: int = field(default=4, metadata={"min": 0})  # the first validation pairs (0: off)
    watch_every: int = field(default=0, metadata={"min": 0})  # steps between frames; 0: at each checkpoint
    export_dtype: str = field(default="float16", metadata=_choices("float16", "float32"))


SECTIONS: dict[str, type] = {"model": ModelSection, "data": DataSection, "train": TrainSection}
TOP_SCALARS = {"base": str, "description": str}


@dataclass
class Recipe:
    model: ModelSection = field(default_factory=ModelSection)
    data: DataSection = field(default_factory=DataSection)
    train: TrainSection = field(default_factory=TrainSection)
    description: str = ""
    path: str = ""  # the recipe file it was loaded from ("" when built in code)

    def to_dict(self) -> dict[str, Any]:
        """Plain TOML-like dict (what checkpoints store); ``from_dict`` reads it back."""
        return {"model": asdict(self.model), "data": asdict(self.data), "train": asdict(self.train),
                "description": self.description, "path": self.path}

    @classmethod
    def from_dict(cls, d: dict[str, Any], origin: str = "recipe") -> Recipe:
        d = dict(d)
        path = d.pop("path", "")
        _check_layer(d, origin, allow_variants=False)
        return _build(d, path=str(path or ""), origin=origin)

    def fnet_config(self, norm_frame: tuple[float, ...] = ()):
        """The :class:`fviz.models.FNetConfig` of this recipe's model; ``norm_frame`` read from the data
        (``model.norm_frame = "unrectified"``: :func:`fviz.train.splits.network_config`)."""
        from fviz.models.model import FNetConfig

        m = self.model
        return FNetConfig.from_variant(
            m.variant, input_hw=tuple(m.input_size), width=m.width, pool_grid=tuple(m.pool_grid),
            hidden=m.hidden, dropout=m.dropout, conditioned=m.conditioned, norm_frame=tuple(norm_frame),
        )

    @property
    def input_hw(self) -> tuple[int, int]:
        return int(self.model.input_size[0]), int(self.model.input_size[1])

    @property
    def kind(self) -> str:
        return self.data.kind or ("stereo" if self.data.source == "kitti-raw" else "temporal")

    @property
    def kinds(self) -> list[str]:
        return list(self.data.kinds) or [self.kind]

    @property
    def cams(self) -> tuple[int, int]:
        if self.data.cams:
            return int(self.data.cams[0]), int(self.data.cams[1])
        return (0, 1) if self.kind == "stereo" else (0, 0)


# ----------------------------------------------------------------------------------------------- types


def _type_name(tp) -> str:
    origin = typing.get_origin(tp)
    if origin is list:
        return f"a list of {_type_name(typing.get_args(tp)[0])}s"
    return {bool: "bool", int: "int", float: "float", str: "string", dict: "table"}.get(tp, str(tp))


def _coerce(value: Any, tp, meta: dict, where: str) -> Any:
    """Check ``value`` against the annotation ``tp`` (:func:`fviz.schema.convert`, the one validator; ints widened to
    float) and the field's bounds (``choices``, ``min``, ``max``; a list's ``len``, each item's bounds); return it."""
    from fviz.schema import convert

    try:
        value = convert(value, tp, where)
    except FvizError:
        if tp is float and isinstance(value, float) and not math.isfinite(value):
            raise FvizError(f"{where} must be a finite number, got {value!r}") from None
        if typing.get_origin(tp) is list and isinstance(value, list):  # an item's type: named at its index
            (item_tp,) = typing.get_args(tp)
            for i, v in enumerate(value):
                _coerce(v, item_tp, {}, f"{where}[{i}]")
        raise FvizError(f"{where} must be {'a' if tp is not int else 'an'} {_type_name(tp)}, got {value!r} "
                        f"({type(value).__name__})") from None
    if typing.get_origin(tp) is list:
        bounds = {k: v for k, v in meta.items() if k in ("min", "max", "choices")}
        for i, v in enumerate(value):
            _bounded(v, bounds, f"{where}[{i}]")
        n = meta.get("len")
        if n is not None and len(value) != n and not (meta.get("allow_empty") and not value):
            raise FvizError(f"{where} must have {n} entries, got {len(value)}")
        return value
    return _bounded(value, meta, where)


def _bounded(value: Any, meta: dict, where: str) -> Any:
    if "choices" in meta and value not in meta["choices"]:
        shown = ", ".join(repr(c) for c in meta["choices"])
        raise FvizError(f"{where} must be one of {shown}, got {value!r}")
    if "min" in meta and value < meta["min"]:
        raise FvizError(f"{where} must be >= {meta['min']}, got {value!r}")
    if "max" in meta and value > meta["max"]:
        raise FvizError(f"{where} must be <= {meta['max']}, got {value!r}")
    return value


def _fields(section_cls) -> dict[str, tuple[Any, dict]]:
    hints = typing.get_type_hints(section_cls)
    return {f.name: (hints[f.name], dict(f.metadata)) for f in fields(section_cls)}


def _check_section(name: str, table: Any, origin: str) -> dict:
    if not isinstance(table, dict):
        raise FvizError(f"{origin}: '{name}' must be a table, got {table!r}")
    spec = _fields(SECTIONS[name])
    out = {}
    for key, value in table.items():
        if key not in spec:
            raise FvizError(f"{origin}: unknown key '{name}.{key}' (known: {', '.join(spec)})")
        tp, meta = spec[key]
        out[key] = _coerce(value, tp, meta, f"{origin}: {name}.{key}")
    return out


def _check_layer(d: dict, origin: str, allow_variants: bool = True) -> dict:
    """Validate one layer (a file, a variants table, one --set) in place; returns it."""
    for key, value in list(d.items()):
        if key in SECTIONS:
            d[key] = _check_section(key, value, origin)
        elif key in TOP_SCALARS:
            if not isinstance(value, TOP_SCALARS[key]):
                raise FvizError(f"{origin}: '{key}' must be a string, got {value!r}")
        elif key == "variants" and allow_variants:
            from fviz.models.model import VARIANTS

            if not isinstance(value, dict):
                raise FvizError(f"{origin}: 'variants' must be a table of [variants.NAME] tables")
            for vname, table in value.items():
                if vname not in VARIANTS:
                    raise FvizError(f"{origin}: unknown variant 'variants.{vname}' (e.g. 'siamese-rec-pos-fbn')")
                if not isinstance(table, dict):
                    raise FvizError(f"{origin}: 'variants.{vname}' must be a table")
                extra = sorted(set(table) - set(SECTIONS))
                if extra:
                    raise FvizError(f"{origin}: unknown key 'variants.{vname}.{extra[0]}' (only model, data, train)")
                _check_layer(table, f"{origin} [variants.{vname}]", allow_variants=False)
                if "variant" in table.get("model", {}):
                    raise FvizError(f"{origin}: 'variants.{vname}.model.variant' cannot be overridden")
        else:
            known = ", ".join([*SECTIONS, *TOP_SCALARS, "variants"])
            raise FvizError(f"{origin}: unknown key '{key}' (known: {known})")
    return d


def _merge(lower: dict, upper: dict) -> dict:
    out = copy.deepcopy(lower)
    for key, value in upper.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


# ----------------------------------------------------------------------------------------------- loading


def _read_toml(path: Path, origin: str) -> dict:
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise FvizError(f"{origin}: file not found") from None
    except IsADirectoryError:
        raise FvizError(f"{origin}: is a directory, expected a .toml file") from None
    except tomllib.TOMLDecodeError as exc:
        raise FvizError(f"{origin}: invalid TOML: {exc}") from None


def _load_chain(path: Path, seen: tuple[Path, ...] = ()) -> dict:
    origin = f"recipe {path}"
    resolved = path.resolve()
    if resolved in seen:
        raise FvizError(f"{origin}: 'base' chain loops back to {path}")
    d = _check_layer(_read_toml(path, origin), origin)
    base = d.pop("base", None)
    if base:
        base_path = Path(os.path.expanduser(os.path.expandvars(base)))
        if not base_path.is_absolute():
            base_path = path.parent / base_path
        if not base_path.exists():
            raise FvizError(f"{origin}: base recipe {base_path} not found")
        lower = _load_chain(base_path, (*seen, resolved))
        variants = _merge(lower.pop("variants", {}), d.pop("variants", {}))
        d = _merge(lower, d)
        if variants:
            d["variants"] = variants
    return d


def parse_set(item: str) -> tuple[list[str], Any]:
    """"train.lr=3e-4" -> (["train", "lr"], 0.0003).  The value is TOML; a bare word is a string."""
    origin = f"--set {item}"
    if "=" not in item:
        raise FvizError(f"{origin}: expected KEY=VALUE, e.g. --set train.lr=3e-4")
    key, raw = item.split("=", 1)
    key, raw = key.strip(), raw.strip()
    parts = key.split(".")
    if not key or any(not p for p in parts):
        raise FvizError(f"{origin}: bad key {key!r}")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return parts, value


def _set_layer(item: str) -> dict:
    parts, value = parse_set(item)
    origin = f"--set {item}"
    if parts[0] not in SECTIONS:
        raise FvizError(f"{origin}: unknown key '{'.'.join(parts)}' (keys start with model., data. or train.)")
    if len(parts) == 1:
        raise FvizError(f"{origin}: '{parts[0]}' is a table; set one of its keys, e.g. {parts[0]}.KEY=VALUE")
    if len(parts) > 2 and not (parts[0] == "data" and parts[1] == "synthetic"):
        raise FvizError(f"{origin}: unknown key '{'.'.join(parts)}'")
    layer: dict = {}
    node = layer
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = value
    return _check_layer(layer, origin, allow_variants=False)


def _build(d: dict, path: str, origin: str) -> Recipe:
    sections = {name: cls(**d.get(name, {})) for name, cls in SECTIONS.items()}
    recipe = Recipe(**sections, description=d.get("description", ""), path=path)
    try:
        recipe.fnet_config()
    except FvizError as exc:
        raise FvizError(f"{origin}: model.variant: {exc}") from None
    if recipe.data.source == "synthetic" and isinstance(recipe.data.synthetic, dict):
        try:
            import fviz.data.synthetic  # noqa: F401  (without it the data fail later, with their own message)
        except ImportError:
            return recipe
        try:  # an input size the renderer refuses is named by its recipe key now, not when training starts
            scene_config(recipe.input_hw, recipe.data.synthetic)
        except FvizError as exc:
            raise FvizError(f"{origin}: {exc}") from None
    return recipe


def load_recipe(path: str | Path, overrides: list[str] | tuple[str, ...] = ()) -> Recipe:
    """Read, merge and validate a recipe (see the module docstring).  Raises FvizError."""
    path = Path(path)
    merged = _load_chain(path)
    sets = [_set_layer(item) for item in overrides]
    probe = merged
    for layer in sets:
        probe = _merge(probe, layer)
    variant = probe.get("model", {}).get("variant", ModelSection.variant)
    from fviz.models.model import parse_variant, variant_name

    try:
        variant = variant_name(**parse_variant(variant))
    except FvizError as exc:
        raise FvizError(f"recipe {path}: model.variant: {exc}") from None
    variants = merged.pop("variants", {})
    if variant in variants:
        merged = _merge(merged, variants[variant])
    for layer in sets:
        merged = _merge(merged, layer)
    merged.setdefault("model", {})["variant"] = variant
    return _build(merged, path=str(path), origin=f"recipe {path}")


def synthetic_api():
    try:
        from fviz.data import synthetic
    except ImportError as exc:
        raise FvizError(f"data.source 'synthetic' needs fviz.data.synthetic, which cannot be imported: {exc}") from None
    return synthetic


def scene_config(input_hw: tuple[int, int], extra: dict):
    """SceneConfig(width=W, height=H, **extra), unknown fields reported as FvizError."""
    synthetic = synthetic_api()
    if "width" in extra or "height" in extra:
        raise FvizError("data.synthetic: width/height come from model.input_size; do not set them here")
    try:
        return synthetic.SceneConfig(width=int(input_hw[1]), height=int(input_hw[0]), **extra)
    except TypeError as exc:
        raise FvizError(f"data.synthetic: {exc}") from None
    except FvizError as exc:
        text = str(exc)
        for field, i in (("SceneConfig.width", 1), ("SceneConfig.height", 0)):
            if text.startswith(field):  # the size is the recipe's model.input_size [H, W]: name that key
                import re

                bounds = re.search(r"\[(\d+), (\d+)\]", text)
                span = f" of {bounds[1]} to {bounds[2]} pixels" if bounds else ""
                raise FvizError(f"model.input_size {list(map(int, input_hw))}: the synthetic scenes need a "
                                f"{'width (W)' if i else 'height (H)'}{span}, got {int(input_hw[i])} "
                                "(model.input_size is [H, W])") from None
        raise


def resolve_path(p: str) -> Path:
    """Expand ``~`` and ``$VARS`` of a recipe path (relative paths stay relative to the working directory)."""
    return Path(os.path.expanduser(os.path.expandvars(p)))
