"""What watching a training run costs: ``train.watch_pairs`` validation pairs logged into train.rrd
(fviz.log_training_step) against the training step, on a CPU recipe.

Runs the recipe (default ``recipes/synthetic_small.toml``, shortened to ``--steps`` steps, a checkpoint every
``--checkpoint-every`` steps: a frame of the watched pairs each, and train.rrd rewritten with every frame so far)
and prints, from the same run, the mean optimizer step (batch, forward, backward, update), the time spent on the
watched pairs (their forward passes, building them once, and logging every frame at every rewrite of train.rrd)
per step, and their ratio; the budget is 5 %. A second run without watched pairs gives the whole-run difference.

Measured 2026-12-02 on the shared 2-core machine (load average 17-22, so steps ran 0.6-1.9 s instead of ~0.15 s):
200 steps, checkpoint every 50, 4 pairs at each checkpoint: 7.5 ms per step, 0.64 % of the step (1.2 s);
100 steps, checkpoint every 25, 4 pairs every 10 steps: 42.7 ms per step, 3.3 % of the step (1.3 s). Every rewrite
of train.rrd logs all frames so far again: the cost grows with frames x checkpoints (watch_every small, long runs).

Usage: python benchmarks/bench_train_record.py [--recipe R] [--steps N] [--checkpoint-every K] [--watch-pairs P]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from common import PROJECT

from fviz.train.loop import train
from fviz.train.recipe import load_recipe


def run(recipe_path: Path, out: Path, steps: int, every: int, pairs: int, watch_every: int):
    recipe = load_recipe(recipe_path, [f"train.max_steps={steps}", f"train.checkpoint_every={every}",
                                       f"train.val_every={steps}", f"train.watch_pairs={pairs}",
                                       f"train.watch_every={watch_every}", f"train.out_dir={out}"])
    return train(recipe, record=True, held_out=False)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recipe", type=Path, default=PROJECT / "recipes" / "synthetic_small.toml")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--checkpoint-every", type=int, default=50)
    ap.add_argument("--watch-pairs", type=int, default=4)
    ap.add_argument("--watch-every", type=int, default=0, help="steps between frames (0: at each checkpoint)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        on = run(args.recipe, Path(tmp) / "on", args.steps, args.checkpoint_every, args.watch_pairs, args.watch_every)
        off = run(args.recipe, Path(tmp) / "off", args.steps, args.checkpoint_every, 0, args.watch_every)
        size = on.recording.stat().st_size / 1e6
    step = on.step_seconds / on.step
    watch = on.watch_seconds / on.step
    print(f"{args.recipe.name}: {on.step} steps, a checkpoint every {args.checkpoint_every}, {args.watch_pairs} watched "
          f"pairs ({'at each checkpoint' if not args.watch_every else f'every {args.watch_every} steps'}); train.rrd {size:.2f} MB")
    print(f"  optimizer step          {1e3 * step:8.2f} ms (mean, same run)")
    print(f"  watched pairs per step  {1e3 * watch:8.2f} ms ({1e3 * on.watch_seconds:.0f} ms in all)")
    print(f"  ratio                   {100 * watch / step:8.2f} % of a step (budget 5 %)")
    print(f"  without watched pairs: optimizer step {1e3 * off.step_seconds / off.step:.2f} ms; whole runs {on.seconds:.1f} s "
          f"watched, {off.seconds:.1f} s without (two runs: a shared machine's noise included)")


if __name__ == "__main__":
    main()
