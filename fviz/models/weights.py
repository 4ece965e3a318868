"""Reading model files (checkpoints of ``fviz train`` and exported weights) back into networks.

    {"format": "fviz-fnet", "format_version": 1, "variant": "siamese-rec-pos-fbn",
     "model_config": FNetConfig.to_dict(), "model_state": state_dict, ...}

(the full layout, and writing, live in :mod:`fviz.train.checkpoint`).  Files are read with
``torch.load(weights_only=True)``: nothing in them executes code.  Every failure is one
:class:`FvizError` sentence naming the file:

- :func:`read_checkpoint`: the file's dict, checked for the format marker;
- :func:`load_into`: weights into an existing model; another variant or config is refused, and
  weights that do not fit the architecture the file names say which tensors differ;
- :func:`load_model`: ``(model in eval mode, metadata)`` built from the file's own ``model_config``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from fviz.errors import FvizError

FORMAT = "fviz-fnet"
FORMAT_VERSION = 1
_TENSOR_KEYS = ("model_state", "optimizer_state", "scaler_state", "rng_state")


def _unwrap(model: torch.nn.Module) -> torch.nn.Module:
    return getattr(model, "module", model)


def _unreadable_reason(exc: Exception) -> str:
    """A short, complete reason for torch.load's failure (torch's own text is long and advises weights_only=False)."""
    text = str(exc)
    if "Unsupported global" in text or "WeightsUnpickler" in text or "weights_only" in text:
        return "it holds Python objects other than tensors and plain data, which fviz does not execute"
    if "zip archive" in text or "central directory" in text or "invalid load key" in text or "magic number" in text:
        return "it is not a torch file, or it is truncated"
    if isinstance(exc, (EOFError,)):
        return "it is empty or truncated"
    if isinstance(exc, OSError):
        return exc.strerror or type(exc).__name__
    return f"torch cannot read it ({type(exc).__name__})"


def state_digest(ckpt: dict[str, Any]) -> str:
    """sha256 of what a model is rebuilt from: variant, model_config and every tensor of model_state (name,
    dtype, shape, bytes). Written as ``state_digest`` with the file; :func:`read_checkpoint` checks it."""
    import hashlib
    import json

    h = hashlib.sha256()
    h.update(json.dumps([ckpt.get("variant"), ckpt.get("model_config")], sort_keys=True, default=str).encode())
    for name in sorted(ckpt["model_state"]):
        v = ckpt["model_state"][name]
        h.update(f"\x00{name}".encode())
        if isinstance(v, torch.Tensor):
            t = v.detach().to("cpu").contiguous().reshape(-1)
            h.update(f"{v.dtype}{tuple(v.shape)}".encode())
            h.update(t.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
        else:
            h.update(repr(v).encode())
    return h.hexdigest()


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load and check a model file; FvizError when it is missing or not an fviz model."""
    path = Path(path)
    if path.is_dir():
        raise FvizError(f"{path}: is a folder, expected a model file (.pt)")
    if not path.is_file():
        raise FvizError(f"{path}: checkpoint not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a foreign or corrupt file
        with open(path, "rb") as f:  # neither a zip (torch >= 1.6) nor a pickle: not a torch file at all
            head = f.read(2)
        torch_file = head == b"PK" or head[:1] == b"\x80"
        reason = _unreadable_reason(exc) if torch_file else "it is not a torch file"
        raise FvizError(f"{path}: not an fviz model checkpoint ({reason})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise FvizError(f"{path}: not an fviz model checkpoint (no '{FORMAT}' format marker)")
    if not isinstance(ckpt.get("format_version", 0), int) or ckpt.get("format_version", 0) > FORMAT_VERSION:
        raise FvizError(
            f"{path}: checkpoint format version {ckpt.get('format_version')!r} is newer than this fviz reads "
            f"({FORMAT_VERSION}); upgrade fviz"
        )
    for key in ("model_config", "model_state"):
        if not isinstance(ckpt.get(key), dict):
            raise FvizError(f"{path}: not an fviz model checkpoint (no {key})")
    stored = ckpt.get("state_digest")  # files of fviz before the digest have none (the bundled weights among them)
    if stored is not None and (not isinstance(stored, str) or stored != state_digest(ckpt)):
        raise FvizError(f"{path}: damaged: its weights do not match the digest written with them (state_digest); "
                        "the file changed after fviz wrote it (retrain, or restore it from a copy)")
    return ckpt


def metadata(ckpt: dict, path: str | Path) -> dict[str, Any]:
    """Everything of a checkpoint but its tensors, plus ``path``."""
    return {k: v for k, v in ckpt.items() if k not in _TENSOR_KEYS} | {"path": str(path)}


def _describe(config: dict) -> str:
    """'siamese-rec-pos-fbn (width 64, hidden 256, input 64x208, pool 3x10)' of a model_config dict."""
    from fviz.models.model import variant_name

    try:
        name = variant_name(config["arch"], config["head"], bool(config["pos"]), config["norm"])
    except (KeyError, FvizError):
        name = "unknown variant"
    hw, grid = config.get("input_hw") or ("?", "?"), config.get("pool_grid") or ("?", "?")
    frame = ", normalized in a calibrated frame" if config.get("norm_frame") else ""
    return f"{name} (width {config.get('width')}, hidden {config.get('hidden')}, input {hw[0]}x{hw[1]}, pool {grid[0]}x{grid[1]}{frame})"


def _state_mismatch(theirs: dict, ours: dict) -> str:
    """What differs between a file's state dict and a model's: counts and the first differing tensor."""
    missing = [k for k in ours if k not in theirs]
    extra = [k for k in theirs if k not in ours]
    shapes = [k for k in ours if k in theirs and tuple(theirs[k].shape) != tuple(ours[k].shape)]
    parts = []
    if shapes:
        k = shapes[0]
        parts.append(f"{len(shapes)} tensor(s) of another shape, e.g. {k} {tuple(theirs[k].shape)} vs {tuple(ours[k].shape)}")
    if missing:
        parts.append(f"{len(missing)} missing, e.g. {missing[0]}")
    if extra:
        parts.append(f"{len(extra)} unexpected, e.g. {extra[0]}")
    return "; ".join(parts) or "tensors differ"


def load_into(model: torch.nn.Module, checkpoint: str | Path | dict, *, what: str | None = None) -> dict[str, Any]:
    """Load a checkpoint's weights into ``model``; FvizError when it holds another variant or config.

    Returns the checkpoint's metadata (everything but the tensors).
    """
    ckpt = checkpoint if isinstance(checkpoint, dict) else read_checkpoint(checkpoint)
    where = what or (str(checkpoint) if not isinstance(checkpoint, dict) else "checkpoint")
    m = _unwrap(model)
    theirs, ours = ckpt.get("variant"), m.config.variant
    if theirs != ours:
        raise FvizError(f"{where}: holds variant '{theirs}', which cannot be loaded into a '{ours}' model")
    mine = m.config.to_dict()
    diff = [k for k in mine if k in ckpt["model_config"] and ckpt["model_config"][k] != mine[k]]
    if diff:
        k = diff[0]
        raise FvizError(f"{where}: model {k} is {ckpt['model_config'][k]!r} in the checkpoint but {mine[k]!r} in this model")
    state = ckpt["model_state"]
    expected = m.state_dict()
    if set(state) != set(expected) or any(tuple(state[k].shape) != tuple(expected[k].shape) for k in expected):
        raise FvizError(
            f"{where}: its weights do not fit the network its config names, {_describe(mine)} "
            f"({_state_mismatch(state, expected)}, in the file vs expected)"
        )
    m.load_state_dict(state, strict=True)
    return metadata(ckpt, where)


def load_model(path: str | Path, device: str | torch.device = "cpu") -> tuple[torch.nn.Module, dict[str, Any]]:
    """(model in eval mode on ``device``, metadata) from a checkpoint or exported weights file."""
    from fviz.models.model import FNet, FNetConfig

    path = Path(path)
    ckpt = read_checkpoint(path)
    try:
        config = FNetConfig.from_dict(ckpt["model_config"])
    except (FvizError, TypeError, ValueError, IndexError) as exc:
        raise FvizError(f"{path}: unusable model config ({exc})") from None
    model = FNet.from_config(config)
    meta = load_into(model, ckpt, what=str(path))
    return model.to(device).eval(), meta
