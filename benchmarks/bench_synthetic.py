"""Throughput of the synthetic pair generator (fviz.data.synthetic).

Prints pairs/s of ``render_batch`` (images + F, no correspondences) at 1242x375 on the CPU for a
few batch sizes; on CUDA, when available, at the training input 320x96 and at 1242x375, with the
batch replayed as a CUDA graph (the default) and run eagerly; and ms per ``synthetic_pair`` (with
the exact correspondences).  Usage: python benchmarks/bench_synthetic.py [--seconds S] [--threads N ...]
"""

from __future__ import annotations

import argparse
import time

import torch

from fviz.data.synthetic import batch as synthetic_batch
from fviz.data.synthetic import SceneConfig, render_batch, synthetic_pair


def pairs_per_second(batch: int, seconds: float, device: str, cfg: SceneConfig) -> float:
    """Render batches of consecutive seeds for about ``seconds``; pairs per wall-clock second."""
    for i in range(3):  # warm-up: texture bank, allocator, CUDA graph capture
        render_batch(list(range(i * batch, (i + 1) * batch)), cfg, device)
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    sync()
    done, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        render_batch(list(range(done, done + batch)), cfg, device)
        done += batch
    sync()
    return done / (time.perf_counter() - start)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="time per measurement")
    ap.add_argument("--threads", type=int, nargs="*", help="CPU thread counts to try (default: 1 and torch's)")
    args = ap.parse_args()
    cfg = SceneConfig()
    print(f"render_batch {cfg.width}x{cfg.height}, torch {torch.__version__}, images + F (no correspondences)")
    default_threads = torch.get_num_threads()
    for threads in args.threads or sorted({1, default_threads}):
        torch.set_num_threads(threads)
        for batch in (1, 8, 16):
            rate = pairs_per_second(batch, args.seconds, "cpu", cfg)
            print(f"  cpu  {threads} thread(s) batch {batch:3d}: {rate:7.1f} pairs/s")
    torch.set_num_threads(default_threads)
    if torch.cuda.is_available():
        print(f"cuda: {torch.cuda.get_device_name()}")
        for graphs in (True, False):
            synthetic_batch.CUDA_GRAPHS = graphs
            for c in (SceneConfig(width=320, height=96), cfg):
                for batch in (16, 64, 256):
                    rate = pairs_per_second(batch, args.seconds, "cuda", c)
                    print(f"  cuda {'graph' if graphs else 'eager'} {c.width}x{c.height} batch {batch:3d}: {rate:9.1f} pairs/s"
                          f"  ({batch / rate * 1e3:7.2f} ms/batch, {2 * rate:9.0f} views/s)")
        synthetic_batch.CUDA_GRAPHS = True
    for stereo in (False, True):
        c = SceneConfig(stereo=stereo)
        synthetic_pair(0, c)
        n, start = 0, time.perf_counter()
        while time.perf_counter() - start < args.seconds:
            pair = synthetic_pair(n, c)
            n += 1
        ms = (time.perf_counter() - start) / n * 1000
        kind = "stereo" if stereo else "temporal"
        print(f"synthetic_pair ({kind}, {c.n_points} sampled points, {len(pair.points_a)} kept): {ms:6.1f} ms")


if __name__ == "__main__":
    main()
