"""Model size, CPU speed and short-training accuracy of the paper's networks at several input sizes.

    python benchmarks/bench_models.py                       # sizes 64x208, 96x320, 128x416; 300 steps each
    python benchmarks/bench_models.py --sizes 64x208,96x320 --steps 100 --threads 1 --json out.json
    python benchmarks/bench_models.py --device cuda --steps 2000   # the accuracy part on a GPU

What it measures (the evidence for the defaults in fviz/models/model.py):

1. every variant at the default configuration: parameters and the bytes of its saved weights
   (float32 and float16 state dicts, as torch.save writes them) against the 20 MB budget;
2. for each input size and both architectures (``--head``, default REC; FBN):
   - parameters and file size (they do not depend on the input size: adaptive pooling grid),
   - CPU inference ms per pair (batch 1, eval mode, median of ``--repeat`` runs after warm-up,
     ``predict_F`` preprocessing excluded),
   - after ``--steps`` training steps on synthetic scenes rendered at that size (recipe
     ``--recipe``, default recipes/synthetic_small.toml with the model's size and width replaced), the
     validation EPI-ABS, EPI-SQR and median symmetric epipolar distance, all measured in ONE common
     frame so that sizes are comparable: ``--val`` scenes rendered at 128 x 416, each model run
     through :func:`fviz.models.predict_F` (resize, predict, map F back), points sampled on the
     ground-truth geometry at 128 x 416, F scaled to unit Frobenius norm;
   - the same metrics for a constant "straight ahead" F (R = I, t along the optical axis) as a
     reference a useful model must beat.

Numbers depend on the machine: on a shared CPU, OpenMP threads that wait on each other can make
the timings erratic; ``--threads 1`` gives stable ones.
"""

from __future__ import annotations

import argparse
import io
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fviz.models import VARIANTS, FNet, count_parameters, predict_F  # noqa: E402 (after sys.path: run as a script)
from fviz.models.model import FNetConfig  # noqa: E402

REF_HW = (128, 416)


def state_bytes(model: torch.nn.Module, dtype: torch.dtype) -> int:
    buf = io.BytesIO()
    torch.save({k: v.to(dtype) if v.is_floating_point() else v for k, v in model.state_dict().items()}, buf)
    return buf.tell()


def time_pair(model: FNet, repeat: int) -> float:
    """Median ms of one forward pass at batch 1 (CPU, eval, inference mode)."""
    model = model.eval()
    H, W = model.config.input_hw
    a, b = torch.rand(1, 1, H, W), torch.rand(1, 1, H, W)
    times = []
    with torch.inference_mode():
        for _ in range(5):
            model(a, b)
        for _ in range(repeat):
            t0 = time.perf_counter()
            model(a, b)
            times.append(time.perf_counter() - t0)
    return 1000 * statistics.median(times)


def reference_val(n: int, seed: int = 7):
    """Validation scenes at REF_HW: uint8 images and F (n, 3, 3) in REF_HW pixels."""
    from fviz.data.synthetic import SceneConfig, render_batch

    out = render_batch(list(range(10**8, 10**8 + n)), SceneConfig(width=REF_HW[1], height=REF_HW[0]))
    to_u8 = lambda x: (x[:, 0] * 255).round().to(torch.uint8).numpy()
    return to_u8(out["image_a"]), to_u8(out["image_b"]), out["F"].numpy()


def ref_metrics(F_pred: np.ndarray, F_gt: np.ndarray) -> dict[str, float]:
    from fviz.train.losses import epipolar_metrics, sample_points_on_geometry

    F_gt_t = torch.from_numpy(F_gt)
    xa, xb = sample_points_on_geometry(F_gt_t, REF_HW, 256, torch.Generator().manual_seed(0))
    m = epipolar_metrics(torch.from_numpy(F_pred), xa, xb)
    sed = m["sed"].flatten()
    return {
        "epi_abs": float(m["abs"].mean()),
        "epi_sqr": float(m["abs"].square().mean()),
        "sed_px@128x416": float(sed[torch.isfinite(sed)].median()),
    }


def straight_ahead(n: int) -> np.ndarray:
    from fviz.data.synthetic import intrinsics
    from fviz.geometry import fundamental_from_motion, normalize

    K = intrinsics(REF_HW[1], REF_HW[0])
    F = normalize(fundamental_from_motion(K, K, np.eye(3), np.array([0.0, 0.0, -1.0])), "fbn")
    return np.repeat(F[None], n, 0)


def train_short(arch: str, hw: tuple[int, int], args) -> FNet:
    from fviz.train.checkpoint import load_model
    from fviz.train.loop import train
    from fviz.train.recipe import load_recipe

    overrides = [
        f"model.variant={arch}-{args.head}-fbn", f"model.input_size=[{hw[0]}, {hw[1]}]", f"model.width={args.width}",
        f"train.max_steps={args.steps}", f"train.batch_size={args.batch}", "train.val_every=0", "train.epochs=1000",
        f"train.device={args.device}", "data.val_size=16", f"train.threads={args.threads}",
        f"train.out_dir={tempfile.mkdtemp(prefix='fviz-bench-')}",
    ]
    recipe = load_recipe(args.recipe, overrides)
    res = train(recipe, record=False, progress=args.progress)
    model, _ = load_model(res.checkpoint)
    return model


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="64x208,96x320,128x416", help="input sizes HxW, comma separated")
    ap.add_argument("--archs", default="siamese,single")
    ap.add_argument("--head", default="rec", help="head of the per-size rows: rec, rec-pos, base, base-pos, epi, epi-pos (FBN)")
    ap.add_argument("--steps", type=int, default=300, help="training steps per configuration (0: skip accuracy)")
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--width", type=int, default=128, help="filters of the single-stream block in the accuracy runs")
    ap.add_argument("--val", type=int, default=64, help="validation scenes (rendered at 128x416)")
    ap.add_argument("--repeat", type=int, default=30, help="timed forward passes")
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch default)")
    ap.add_argument("--device", default="auto", help="training device for the accuracy runs")
    ap.add_argument("--recipe", default=str(ROOT / "recipes" / "synthetic_small.toml"))
    ap.add_argument("--progress", action="store_true")
    ap.add_argument("--json", help="write all numbers to this file")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    from rich.console import Console
    from rich.table import Table

    console = Console(width=max(Console().width, 150))
    report: dict = {"threads": torch.get_num_threads(), "torch": str(torch.__version__), "variants": [], "sizes": []}

    table = Table(title=f"All variants at the default configuration ({FNetConfig().input_hw[0]}x{FNetConfig().input_hw[1]})")
    for col in ("variant", "params", "MB fp32", "MB fp16", "< 20 MB"):
        table.add_column(col, justify="right" if col != "variant" else "left")
    for name in VARIANTS:
        torch.manual_seed(0)
        m = FNet.from_variant(name)
        n, b32, b16 = count_parameters(m), state_bytes(m, torch.float32), state_bytes(m, torch.float16)
        report["variants"].append({"variant": name, "params": n, "bytes_fp32": b32, "bytes_fp16": b16})
        table.add_row(name, f"{n:,}", f"{b32 / 1e6:.2f}", f"{b16 / 1e6:.2f}", "yes" if b32 < 20e6 else "NO")
    console.print(table)

    sizes = [tuple(int(v) for v in s.lower().split("x")) for s in args.sizes.split(",")]
    archs = args.archs.split(",")
    val = None
    if args.steps:
        val = reference_val(args.val)
        base = ref_metrics(straight_ahead(args.val), val[2])
        report["straight_ahead_baseline"] = base
        console.print("constant straight-ahead F: " + "  ".join(f"{k} {v:.4g}" for k, v in base.items()))

    table = Table(title=f"{args.head.upper()} FBN per input size ({torch.get_num_threads()} CPU threads; accuracy after {args.steps} steps, batch {args.batch}, width {args.width})")
    for col in ("arch", "input", "params", "MB fp32", "MB fp16", "CPU ms/pair", "EPI-ABS", "EPI-SQR", "SED px@128x416", "train s"):
        table.add_column(col, justify="right")
    for hw in sizes:
        for arch in archs:
            torch.manual_seed(0)
            m = FNet.from_variant(f"{arch}-{args.head}-fbn", input_hw=hw)
            row = {"arch": arch, "input_hw": list(hw), "params": count_parameters(m),
                   "bytes_fp32": state_bytes(m, torch.float32), "bytes_fp16": state_bytes(m, torch.float16),
                   "cpu_ms_per_pair": time_pair(m, args.repeat)}
            if args.steps:
                t0 = time.perf_counter()
                trained = train_short(arch, hw, args)
                row["train_seconds"] = time.perf_counter() - t0
                trained = trained.cpu().eval()
                F_pred = np.stack([predict_F(trained, a, b) for a, b in zip(val[0], val[1])])
                row.update(ref_metrics(F_pred, val[2]))
                row["train_width"] = args.width
            report["sizes"].append(row)
            table.add_row(
                arch, f"{hw[0]}x{hw[1]}", f"{row['params']:,}", f"{row['bytes_fp32'] / 1e6:.2f}", f"{row['bytes_fp16'] / 1e6:.2f}",
                f"{row['cpu_ms_per_pair']:.1f}", *(f"{row[k]:.4g}" if k in row else "-" for k in ("epi_abs", "epi_sqr", "sed_px@128x416")),
                f"{row['train_seconds']:.0f}" if "train_seconds" in row else "-",
            )
            console.print(f"  done {arch} {hw[0]}x{hw[1]}", style="dim")
    console.print(table)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2))
        console.print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
