"""Checkpoints: one torch file holding everything needed to rebuild, resume or audit a model.

    {
      "format": "fviz-fnet", "format_version": 1,
      "variant": "siamese-rec-pos-fbn", "model_config": FNetConfig.to_dict(),
      "model_state": state_dict (float32, or float16 in exported weights files),
      "optimizer_state": ... | None, "scaler_state": ... | None,
      "recipe": Recipe.to_dict() | None, "metrics": {"last": {...}, "history": [...]},
      "step": int, "epoch": int, "batch_in_epoch": int,
      "code_version": {"fviz": "0.1.0", "git": "<commit>" | None, "torch": "2.x"},
      "recording_id": str | None, "rng_state": ByteTensor | None,
      "curves": {entity: ([step, ...], [value, ...])} (the training curves, to rewrite train.rrd on resume),
    }

Files are written atomically (a temporary name in the same folder, then ``os.replace``) so a crash
never leaves a half-written checkpoint in place of the last good one.  They are read with
``torch.load(weights_only=True)``: nothing in them executes code.

Reading files back (``load_model``, ``load_into``, ``read_checkpoint``) belongs to the models:
:mod:`fviz.models.weights` (re-exported here for the training code).

- :func:`export_weights` writes a small weights-only copy (float16 by default: what gets bundled).
- :class:`RunState`: where a training run stands, what ``last.pt`` carries beside the weights and the optimizer;
  :func:`resume_state` loads a ``last.pt`` back into a run (``fviz train --resume``).
- The run's folder: :func:`output_dir` (``train.out_dir``), :func:`check_fresh` (a fresh run overwrites no
  ``last.pt`` or ``model.pt``), :func:`make_out_dir`.
"""

from __future__ import annotations

import os
import subprocess
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from fviz.errors import FvizError
from fviz.models.weights import FORMAT, FORMAT_VERSION, load_into, load_model, read_checkpoint
from fviz.train.recipe import Recipe, resolve_path

__all__ = ["RunState", "atomic_save", "check_fresh", "export_weights", "load_into", "load_model", "make_checkpoint", "make_out_dir",
           "output_dir", "read_checkpoint", "resume_state", "save_checkpoint"]


def git_commit() -> str | None:
    """The commit of the fviz source tree, when it is a git checkout (else None)."""
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    commit = out.stdout.strip()
    return commit if out.returncode == 0 and len(commit) == 40 else None


def code_version() -> dict[str, Any]:
    from fviz.version import __version__

    return {"fviz": __version__, "git": git_commit(), "torch": str(torch.__version__)}


def _unwrap(model: torch.nn.Module) -> torch.nn.Module:
    return getattr(model, "module", model)


def atomic_save(obj: Any, path: str | Path) -> Path:
    """torch.save to a temporary file beside ``path``, then rename over it."""
    from fviz.atomic import replacing

    if isinstance(obj, dict) and obj.get("format") == FORMAT and isinstance(obj.get("model_state"), dict):
        obj = _sealed(obj)  # a flipped bit in the weights is refused when read back
    from fviz.atomic import WriteError

    try:
        with replacing(path) as tmp:
            torch.save(obj, tmp)
    except RuntimeError as exc:  # torch's zip writer reports a full disk or a size limit as RuntimeError ("unexpected pos")
        raise WriteError(f"cannot write {path}: the write failed, disk full or a file size limit? "
                         f"(torch: {' '.join(str(exc).split())[:100]}); its previous version is kept") from None
    return Path(path)


def make_checkpoint(
    model: torch.nn.Module,
    *,
    optimizer: torch.optim.Optimizer | None = None,
    scaler: Any = None,
    recipe: dict | None = None,
    metrics: dict | None = None,
    step: int = 0,
    epoch: int = 0,
    batch_in_epoch: int = 0,
    recording_id: str | None = None,
    dtype: torch.dtype | None = None,
    version: dict | None = None,
) -> dict[str, Any]:
    m = _unwrap(model)
    state = {k: v.detach().to("cpu") for k, v in m.state_dict().items()}
    if dtype is not None:
        state = {k: v.to(dtype) if v.is_floating_point() else v for k, v in state.items()}
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "variant": m.config.variant,
        "model_config": m.config.to_dict(),
        "model_state": state,
        "optimizer_state": optimizer.state_dict() if optimizer is not None else None,
        "scaler_state": scaler.state_dict() if scaler is not None and scaler.is_enabled() else None,
        "recipe": recipe,
        "metrics": metrics or {},
        "step": int(step),
        "epoch": int(epoch),
        "batch_in_epoch": int(batch_in_epoch),
        "code_version": version or code_version(),
        "recording_id": recording_id,
        "rng_state": torch.get_rng_state(),
    }


def _sealed(ckpt: dict[str, Any]) -> dict[str, Any]:
    """The checkpoint with its ``state_digest`` (:func:`fviz.models.weights.state_digest`)."""
    from fviz.models.weights import state_digest

    return {**ckpt, "state_digest": state_digest(ckpt)}


def save_checkpoint(path: str | Path, model: torch.nn.Module, **kw) -> Path:
    """Write a checkpoint atomically (keywords as :func:`make_checkpoint`)."""
    return atomic_save(make_checkpoint(model, **kw), path)


def export_weights(src: str | Path, dst: str | Path, dtype: str = "float16") -> Path:
    """Weights-only copy of a checkpoint (no optimizer state), float16 or float32; loadable by :func:`load_model`."""
    ckpt = read_checkpoint(src)
    dt = {"float16": torch.float16, "float32": torch.float32}.get(dtype)
    if dt is None:
        raise FvizError(f"export dtype must be float16 or float32, got {dtype!r}")
    out = dict(ckpt)
    out["model_state"] = {k: v.to(dt) if v.is_floating_point() else v for k, v in ckpt["model_state"].items()}
    out.update(optimizer_state=None, scaler_state=None, rng_state=None, curves=None)
    return atomic_save(out, dst)


@dataclass
class RunState:
    """Where a training run stands beside its weights and optimizer: what ``last.pt`` carries to resume it."""

    step: int = 0
    epoch: int = 0
    batch_in_epoch: int = 0
    history: list[dict[str, Any]] = field(default_factory=list)  # every validation: {"step", "epoch", metrics...}
    recording_id: str = field(default_factory=lambda: str(uuid.uuid4()))  # train.rrd's, the same across resumes
    curves: dict = field(default_factory=dict)  # fviz.train.curves.Curves.state()
    watch: list = field(default_factory=list)  # per step: the network's F on the watched pairs, the constant's
    notes: list = field(default_factory=list)  # each validation's verdict against the constants, per step
    target_mean: dict = field(default_factory=dict)  # fviz.train.validation.TargetMean.state()


def resume_state(path: Path, model: torch.nn.Module, optimizer: torch.optim.Optimizer, scaler: Any, world: int) -> RunState:
    """Load the run checkpoint ``path`` (last.pt) into the model, optimizer and gradient scaler, and the RNG of a
    single process; -> where the run stood.  FvizError without one, or for a weights-only file."""
    if not path.exists():
        raise FvizError(f"--resume: no checkpoint to resume at {path}")
    ckpt = read_checkpoint(path)
    load_into(model, ckpt, what=str(path))
    if ckpt.get("optimizer_state") is None:
        raise FvizError(f"{path}: holds no optimizer state (an exported weights file?); cannot resume from it")
    optimizer.load_state_dict(ckpt["optimizer_state"])
    if ckpt.get("scaler_state") and scaler.is_enabled():
        scaler.load_state_dict(ckpt["scaler_state"])
    state = RunState(
        step=int(ckpt["step"]), epoch=int(ckpt["epoch"]), batch_in_epoch=int(ckpt.get("batch_in_epoch", 0)),
        history=list(ckpt.get("metrics", {}).get("history", [])), curves=ckpt.get("curves") or {},
        watch=ckpt.get("watch") or [], notes=ckpt.get("notes") or [], target_mean=ckpt.get("target_mean") or {},
    )
    state.recording_id = ckpt.get("recording_id") or state.recording_id
    if ckpt.get("rng_state") is not None and world == 1:
        torch.set_rng_state(ckpt["rng_state"])
    return state


def make_out_dir(out_dir: Path) -> None:
    """Create ``train.out_dir``; FvizError when it cannot be created or written."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FvizError(f"train.out_dir {out_dir}: cannot create it ({exc.strerror})") from None
    if not os.access(out_dir, os.W_OK):
        raise FvizError(f"train.out_dir {out_dir}: not writable")


def check_fresh(out_dir: Path, resume: bool) -> None:
    """A fresh run (no --resume) into an out_dir holding last.pt or model.pt is refused: nothing is overwritten."""
    if not resume and (out_dir / "last.pt").exists():
        raise FvizError(
            f"{out_dir} already holds a checkpoint (last.pt): pass --resume to continue it, or choose another "
            "train.out_dir (e.g. --set train.out_dir=runs/NEW)"
        )
    if not resume and os.path.lexists(out_dir / "model.pt"):  # a finished run's weights, its last.pt removed
        raise FvizError(
            f"{out_dir} already holds a trained model (model.pt, without last.pt to resume): choose another "
            "train.out_dir (e.g. --set train.out_dir=runs/NEW), or move model.pt away to train here again"
        )


def output_dir(recipe: Recipe) -> Path:
    """The recipe's ``train.out_dir`` ({variant} filled in); FvizError when it exists and is not a folder."""
    out_dir = resolve_path(recipe.train.out_dir.replace("{variant}", recipe.model.variant))
    if out_dir.exists() and not out_dir.is_dir():
        raise FvizError(f"train.out_dir {out_dir}: exists and is not a folder (choose another, e.g. --set train.out_dir=runs/NEW)")
    return out_dir
