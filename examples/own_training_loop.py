"""Watch your own network learn: log its F on a few validation pairs every N steps of your PyTorch loop.

    FVIZ_KITTI_ROOT=/path/to/kitti python examples/own_training_loop.py [OUT.rrd] [STEPS]

A tiny CNN learns the fundamental matrix of KITTI odometry 00's temporal pairs (the shared samples); every
LOG_EVERY steps ``fviz.log_training_step`` records its epipolar lines on three held-out pairs beside the ground
truth's. Open ``rerun OUT.rrd`` and scrub the ``step`` timeline: the lines converge. Any
``rerun.RecordingStream`` works: ``rec.spawn()`` for a live viewer, ``rec.notebook_show()`` in Jupyter.
Uses only the public API (``import fviz``); the model, loss and loop are yours.
"""

import os
import sys
from pathlib import Path

import numpy as np
import rerun as rr
import torch

import fviz

root = Path(os.environ.get("FVIZ_KITTI_ROOT", Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti"))
out = Path(sys.argv[1] if len(sys.argv) > 1 else "own_training_loop.rrd")
steps = int(sys.argv[2]) if len(sys.argv) > 2 else 100
LOG_EVERY = 10
torch.manual_seed(0)
torch.set_num_threads(1)

# Pairs with ground truth: frames 0-39 to train on, three later ones to watch.
train_pairs = [fviz.load_pair(root, sequence="00", frame=i, kind="temporal") for i in range(40)]
val_pairs = [fviz.load_pair(root, sequence="00", frame=i, kind="temporal") for i in (44, 46, 48)]
W, H = train_pairs[0].size_a
T = torch.tensor([[2 / W, 0, -1], [0, 2 / W, -H / W], [0, 0, 1]], dtype=torch.float64)  # pixels -> [-1, 1]


def images(pairs):
    """(B, 2, 24, 80) float: both images, downsampled."""
    x = torch.from_numpy(np.stack([np.stack([p.image_a, p.image_b]) for p in pairs])).float() / 255
    return torch.nn.functional.adaptive_avg_pool2d(x, (24, 80))


def conditioned(F_pixels):
    """F in the [-1, 1] frame, unit norm: what the network predicts. (B, 3, 3) -> (B, 3, 3)."""
    F = T.inverse().T @ torch.as_tensor(F_pixels, dtype=torch.float64) @ T.inverse()
    return (F / F.flatten(1).norm(dim=1)[:, None, None]).float()


def to_pixels(F):
    """The network's F in pixels of the pair's images (what fviz takes). (B, 3, 3) -> (B, 3, 3)."""
    return T.T @ F.double() @ T


model = torch.nn.Sequential(
    torch.nn.Conv2d(2, 8, 5, stride=2, padding=2), torch.nn.ReLU(), torch.nn.Conv2d(8, 16, 3, stride=2, padding=1),
    torch.nn.ReLU(), torch.nn.AdaptiveAvgPool2d((2, 5)), torch.nn.Flatten(), torch.nn.Linear(160, 9), torch.nn.Unflatten(1, (3, 3)),
)
opt = torch.optim.Adam(model.parameters(), lr=3e-3)
schedule = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
x_train, F_train = images(train_pairs), conditioned(np.stack([p.F_gt for p in train_pairs]))
x_val = images(val_pairs)

rec = rr.RecordingStream("own-training-loop")
rec.save(str(out))
for step in range(steps + 1):
    if step % LOG_EVERY == 0:  # the watched pairs, in eval mode
        model.eval()
        with torch.no_grad():
            sed = fviz.log_training_step(rec, step, val_pairs, to_pixels(model(x_val)), names=["f44", "f46", "f48"])
        model.train()
        print(f"step {step:4d}: median SED on the watched pairs {np.round(sed, 2).tolist()} px")
    if step == steps:
        break
    batch = torch.randint(0, len(train_pairs), (8,))
    F = model(x_train[batch])
    F = F / F.flatten(1).norm(dim=1)[:, None, None]
    loss = torch.minimum((F - F_train[batch]).abs().mean((1, 2)), (F + F_train[batch]).abs().mean((1, 2))).mean()
    opt.zero_grad()
    loss.backward()
    opt.step()
    schedule.step()
rec.flush()
rec.disconnect()
print("recording:", out)
