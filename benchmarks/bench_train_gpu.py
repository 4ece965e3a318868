"""Does synthetic data generation keep up with training?  (issue target: >= 90 %, on a GPU)

    python benchmarks/bench_train_gpu.py [--recipe recipes/synthetic_bundled.toml] [--steps 60]

Measured in one run, same model, batch size and step (forward, L1+L2 loss, backward, clipped Adam step):
- steps/s on ready-made tensors already on the device (one fixed batch),
- steps/s with every batch's scenes rendered on the device first (fviz.data.synthetic.render_batch),
and the ratio of the two; also generator pairs/s at full KITTI size (1242x375) and at the model input,
and inference ms per pair (batch 1 and batch 64). Runs on the CPU too (slowly), for comparison.
"""

import argparse
import time

import torch

from fviz.data.synthetic import SceneConfig, render_batch
from fviz.models.model import FNet
from fviz.train.losses import f_loss
from fviz.train.runtime import autocast_dtype
from fviz.train.recipe import load_recipe


def sync(device):
    if device.type == "cuda":
        torch.cuda.synchronize()


def rate(fn, n: int, device) -> float:
    """Calls per second of fn over n calls, after 3 warm-up calls."""
    for _ in range(3):
        fn()
    sync(device)
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    sync(device)
    return n / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--recipe", default="recipes/synthetic_bundled.toml")
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = ap.parse_args()
    device = torch.device(args.device)
    recipe = load_recipe(args.recipe)
    t = recipe.train
    H, W = recipe.input_hw
    B = t.batch_size
    norm = recipe.model.variant.rsplit("-", 1)[-1]
    model = FNet.from_config(recipe.fnet_config()).to(device).train()
    opt = torch.optim.Adam(model.parameters(), lr=t.lr)
    amp = autocast_dtype(t.amp, device)
    cfg_small = SceneConfig(width=W, height=H, **recipe.data.synthetic)
    seed = iter(range(10**9))

    def render(config, n):
        return render_batch([next(seed) for _ in range(n)], config, device)

    def step(img_a, img_b, F_t):
        with torch.autocast(device.type, dtype=amp or torch.float32, enabled=amp is not None):
            F_pred = model(img_a, img_b)
        loss = f_loss(F_pred, F_t, norm, t.l1_weight, t.l2_weight, t.loss_frame, (H, W))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()

    fixed = render(cfg_small, B)
    ready = (fixed["image_a"].float(), fixed["image_b"].float(), fixed["F"].float())
    steps_ready = rate(lambda: step(*ready), args.steps, device)

    def rendered_step():
        out = render(cfg_small, B)
        step(out["image_a"].float(), out["image_b"].float(), out["F"].float())

    steps_rendered = rate(rendered_step, args.steps, device)
    gen_small = B * rate(lambda: render(cfg_small, B), max(args.steps // 2, 5), device)
    gen_full = B * rate(lambda: render(SceneConfig(), B), 5, device)
    model.eval()
    with torch.no_grad():
        one = (ready[0][:1], ready[1][:1])
        ms_1 = 1000 / rate(lambda: model(*one), 50, device)
        ms_64 = 1000 / rate(lambda: model(ready[0], ready[1]), 20, device) / B
    print(f"device: {torch.cuda.get_device_name(device) if device.type == 'cuda' else 'cpu'}; model {recipe.model.variant} "
          f"at {H}x{W}, batch {B}, amp {amp}")
    print(f"train steps/s, ready-made tensors : {steps_ready:8.1f}  ({steps_ready * B:.0f} pairs/s)")
    print(f"train steps/s, rendered each step : {steps_rendered:8.1f}  ({steps_rendered * B:.0f} pairs/s)")
    print(f"ratio rendered / ready             : {steps_rendered / steps_ready:8.1%}  (target >= 90 %)")
    print(f"generator pairs/s at {W}x{H}        : {gen_small:8.0f}")
    print(f"generator pairs/s at 1242x375      : {gen_full:8.0f}")
    print(f"inference ms/pair, batch 1 / 64    : {ms_1:8.2f} / {ms_64:.3f}")


if __name__ == "__main__":
    main()
