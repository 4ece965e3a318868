"""Validation of a training run (every epoch, or every ``val_every`` steps): the paper's metrics on ``val_points``
points per pair sampled *on the ground-truth geometry*: x_a uniform in image a, x_b the projection
of a uniform point of image b onto the epipolar line F_t x_a, so x_b^T F_gt x_a = 0 exactly (the
same for synthetic and KITTI pairs: KITTI has no dense correspondences, and for synthetic scenes
these points are exact too; a fixed generator makes them identical across validations):

- ``epi_abs``: mean |x_b^T F x_a| with F scaled to unit Frobenius norm, in model-input pixels;
- ``epi_sqr``: mean (x_b^T F x_a)^2, same F and points;
- ``sed_px``: median symmetric epipolar distance (pixels of the model input);
- ``f_dist``: mean min ||F -+ F_t|| of unit-norm matrices; ``loss``: the training loss;
- beside the network, two constants that read no image, on the same points: ``mean_f_sed_px``, the median SED of
  the mean F of the training pairs stepped on so far (:class:`TargetMean`, travels in ``last.pt``), and
  ``ahead_sed_px``, of straight-ahead motion (:func:`straight_ahead_input_f`); ``mean_f_p`` / ``ahead_p``:
  Wilcoxon's two-sided p of the per-pair median SEDs of the network against each.  The network beats a constant
  when its median SED is lower and p < 0.05 (:func:`beats`); unless it beats both, each validation's line, the
  end of ``fviz train`` and ``train.rrd`` (``val/verdict``) say "the model is no better than the constant"
  (:func:`versus_constants`).  Measured: recipes/synthetic_small.toml ends at 1.641 px against 1.642 / 1.642 px
  (no better); recipes/synthetic_bundled.toml at 1.785 px against 3.014 / 2.672 px (H200, its recipe header).
"""

from __future__ import annotations

import math

import torch

from fviz.train.heldout import NO_BETTER
from fviz.train.losses import epipolar_metrics, f_distance_t, f_loss, sample_points_on_geometry
from fviz.train.recipe import Recipe


VALIDATION_FIGURES = ("loss", "epi_abs", "epi_sqr", "sed_px", "f_dist")  # the network's; then each constant's
CONSTANTS = ("mean_f", "ahead")  # the constants every validation sets the network beside (CONSTANT_NAMES: how they read)
CONSTANT_NAMES = {"mean_f": "the training pairs' mean F", "ahead": "straight-ahead motion"}
BEATS_P = 0.05  # the network beats a constant when Wilcoxon's test of the per-pair median SEDs finds it lower at p < 0.05


@torch.no_grad()
def validate(model, loader, recipe: Recipe, device: torch.device, amp_dtype: torch.dtype | None,
             mean_f: torch.Tensor | None = None) -> dict[str, float]:
    """The validation metrics of ``model`` over ``loader`` (see the module docstring), beside two constants that
    read no image on the same points: ``mean_f`` (the training pairs' mean F, :class:`TargetMean`; without it the
    validation targets' own mean, an oracle) and straight-ahead motion (:func:`straight_ahead_input_f`).
    ``{c}_sed_px``: a constant's median SED; ``{c}_p``: Wilcoxon's two-sided p of the per-pair median SEDs of the
    network against it (:func:`versus_constants` reads them)."""
    norm = recipe.model.variant.rsplit("-", 1)[1]
    t = recipe.train
    was_training = model.training
    model.eval()
    gen = torch.Generator().manual_seed(12345)
    loss_sum, n_pairs, f_sum = 0.0, 0, 0.0
    abs_all, sqr_all, sed_all, targets = [], [], [], []  # targets: (F_t, xa, xb) for the constants' SED
    try:
        for img_a, img_b, F_t in loader:
            img_a, img_b, F_t = img_a.to(device), img_b.to(device), F_t.to(device)
            with torch.autocast(device.type, dtype=amp_dtype or torch.float32, enabled=amp_dtype is not None):
                F_pred = model(img_a, img_b, strict_norm=False)
            B = F_t.shape[0]
            loss_sum += float(f_loss(F_pred, F_t, norm, t.l1_weight, t.l2_weight, t.loss_frame, recipe.input_hw)) * B
            n_pairs += B
            xa, xb = sample_points_on_geometry(F_t, recipe.input_hw, recipe.data.val_points, gen)
            m = epipolar_metrics(F_pred, xa, xb)
            abs_all.append(m["abs"].flatten().cpu())
            sqr_all.append(m["abs"].square().flatten().cpu())
            sed_all.append(m["sed"].cpu())
            targets.append((F_t.double().cpu(), xa.cpu(), xb.cpu()))
            f_sum += float(f_distance_t(F_pred, F_t).sum())
    finally:
        model.train(was_training)
    if n_pairs == 0:
        return {}
    sed = torch.cat(sed_all)
    out = {
        "loss": loss_sum / n_pairs,
        "epi_abs": float(torch.cat(abs_all).mean()),
        "epi_sqr": float(torch.cat(sqr_all).mean()),
        "sed_px": _median(sed),
        "f_dist": f_sum / n_pairs,
    }
    constants = {"mean_f": mean_f if mean_f is not None else mean_target(torch.cat([t[0] for t in targets])),
                 "ahead": straight_ahead_input_f(recipe.input_hw)}
    for name, F_c in constants.items():
        sed_c = constant_sed(F_c, targets)
        out[f"{name}_sed_px"] = _median(sed_c)
        out[f"{name}_p"] = _paired_p(sed, sed_c)
    return out


def _median(sed: torch.Tensor) -> float:
    sed = sed.flatten()
    sed = sed[torch.isfinite(sed)]
    return float(sed.median()) if sed.numel() else float("nan")


def _paired_p(sed: torch.Tensor, sed_c: torch.Tensor) -> float:
    """Wilcoxon's two-sided p of the per-pair median SEDs (B, n) x 2 (:func:`fviz.compare.wilcoxon_signed_rank`)."""
    from fviz.compare import wilcoxon_signed_rank

    d = (sed.nanmedian(dim=1).values - sed_c.nanmedian(dim=1).values).numpy()
    return float(wilcoxon_signed_rank(d).p)


def mean_target(F_t: torch.Tensor) -> torch.Tensor:
    """The mean of targets (B, 3, 3) up to scale and sign: unit Frobenius, signs aligned with the first, made rank 2."""
    F = F_t.double().flatten(1)
    F = F / F.norm(dim=1, keepdim=True).clamp_min(1e-300)
    F = F * torch.where(F @ F[0] < 0, -1.0, 1.0)[:, None].to(F)
    return _rank2(F.mean(0).reshape(3, 3))


def _rank2(F: torch.Tensor) -> torch.Tensor:
    U, S, Vh = torch.linalg.svd(F.double())
    F = U @ torch.diag(torch.stack([S[0], S[1], torch.zeros_like(S[2])])) @ Vh
    return F / F.norm().clamp_min(1e-300)


def straight_ahead_input_f(input_hw: tuple[int, int]) -> torch.Tensor:
    """F of pure forward motion (R = I, t = z) in model-input pixels, for KITTI's camera scaled to the input (the
    synthetic scenes' camera, :func:`fviz.data.synthetic.intrinsics`): K^-T [z]x K^-1 ~ [(cx, cy, 1)]x, lines
    through the principal point.  Unit Frobenius, float64."""
    H, W = int(input_hw[0]), int(input_hw[1])
    try:
        from fviz.data.synthetic import intrinsics

        K = intrinsics(W, H)
        cx, cy = float(K[0, 2]), float(K[1, 2])
    except ImportError:  # the image centre
        cx, cy = (W - 1) / 2, (H - 1) / 2
    F = torch.tensor([[0.0, -1.0, cy], [1.0, 0.0, -cx], [-cy, cx, 0.0]], dtype=torch.float64)
    return F / F.norm()


def constant_sed(F_c: torch.Tensor, targets: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]) -> torch.Tensor:
    """The SED (B, n) of one constant F on the validation points; ``targets``: per batch (F_t, xa, xb (B, n, 3))."""
    F_c = F_c.double().cpu()
    return torch.cat([epipolar_metrics(F_c.expand(len(xa), 3, 3), xa.double(), xb.double())["sed"] for _, xa, xb in targets])


def constant_sed_px(targets: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]) -> float:
    """The median SED on the validation points of the validation targets' own mean F (an oracle: it has seen the
    labels). ``targets``: per batch (F_t (B, 3, 3), xa, xb (B, n, 3))."""
    return _median(constant_sed(mean_target(torch.cat([t[0] for t in targets])), targets))


class TargetMean:
    """The running mean of the training targets the loop has stepped on, unit Frobenius, signs aligned with
    ``ref`` (the training set's first target, as :func:`fviz.estimators.baselines.mean_fundamental` aligns
    with the first of its matrices): the constant F of the training data, what a network that ignores the
    images converges to.  Summed on the training device (no host sync per step); it travels in the
    checkpoint (:meth:`state`)."""

    def __init__(self, state: dict | None = None, ref: torch.Tensor | None = None):
        self.ref = self.sum = self._ref = None
        self.n = 0
        if ref is not None:
            F = ref.detach().double().cpu().flatten()
            self.ref = F / F.norm().clamp_min(1e-300)
        if state and state.get("n"):
            self.ref = torch.tensor(state["ref"], dtype=torch.float64)
            self.sum = torch.tensor(state["sum"], dtype=torch.float64)
            self.n = int(state["n"])

    def add(self, F_t: torch.Tensor) -> None:
        F = F_t.detach().flatten(1)
        F = F.float() if F.device.type == "mps" else F.double()  # MPS has no float64
        F = F / F.norm(dim=1, keepdim=True).clamp_min(1e-30)
        if self.ref is None:
            self.ref = F[0].double().cpu()
        if getattr(self, "_ref", None) is None or self._ref.device != F.device:
            self._ref = self.ref.to(F)  # once per device: no copy per step
        ref = self._ref
        F = F * torch.where(F @ ref < 0, -1.0, 1.0)[:, None]
        s = F.sum(0)
        self.sum = s if self.sum is None else self.sum.to(s) + s
        self.n += F.shape[0]

    def F(self) -> torch.Tensor | None:
        """The rank-2 mean (3, 3), float64 on the CPU; None before the first step."""
        return _rank2(self.sum.double().cpu().reshape(3, 3)) if self.n else None

    def state(self) -> dict:
        if not self.n:
            return {}
        return {"ref": self.ref.tolist(), "sum": self.sum.double().cpu().tolist(), "n": self.n}


def beats(metrics: dict[str, float], constant: str) -> bool:
    """Whether the validation's network beats ``constant`` ("mean_f" or "ahead"): a lower median SED than the
    constant's, and Wilcoxon's test of the per-pair median SEDs finds a difference (p < BEATS_P)."""
    sed, c, p = (metrics.get(k, math.nan) for k in ("sed_px", f"{constant}_sed_px", f"{constant}_p"))
    return bool(sed < c and p < BEATS_P)


def versus_constants(metrics: dict[str, float], what: str = "validation") -> str:
    """One line setting the network beside both constants: "the model beats both constants: ..." or "the model
    is no better than the constant: validation median SED 1.648 px vs 1.651 px for the training pairs' mean F
    (p 0.41) and 1.503 px for straight-ahead motion (p 0.02)"; "" when the metrics lack the constants (a
    checkpoint of an older fviz)."""
    present = [c for c in CONSTANTS if f"{c}_sed_px" in metrics]
    if "sed_px" not in metrics or not present:
        return ""
    figures = " and ".join(f"{metrics[f'{c}_sed_px']:.4g} px for {CONSTANT_NAMES[c]} (p {metrics.get(f'{c}_p', math.nan):.2g})"
                           for c in present)
    lost = [c for c in present if not beats(metrics, c)]
    head = (NO_BETTER if lost else
            f"the model beats {'both constants' if len(present) > 1 else 'the constant'}")
    return f"{head}: {what} median SED {metrics['sed_px']:.4g} px vs {figures}"
