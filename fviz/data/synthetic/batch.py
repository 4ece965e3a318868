"""The training set's generator: :func:`render_batch` renders a batch of seeds' pairs (images, F, cameras) at once.

On a CUDA device it has no host <-> device synchronisation and no Python loop over the batch: it records the whole
batch as a CUDA graph per (config, batch size, device) the first time (at most ``MAX_GRAPHS`` kept, each holding its
work memory; FVIZ_SYNTHETIC_CUDA_GRAPHS=0 runs eagerly) and replays it afterwards, on a side stream of its own that
does not wait for the caller's queued work (FVIZ_SYNTHETIC_SIDE_STREAM=0: on the caller's stream), so the rendering of
the next batch can run on the GPU alongside the current training step; the caller's stream waits for the results.
A GPU renders the same images as the CPU (seen bit-identical on an H100; the texture interpolation could in principle
round differently).
"""

from __future__ import annotations

import math
import numbers
import os
import threading
import warnings
from collections import OrderedDict
from collections.abc import Sequence

import torch

from fviz.data.synthetic.appearance import add_noise, blur
from fviz.data.synthetic.config import SceneConfig, canonical
from fviz.data.synthetic.consts import SceneConsts, scene_consts
from fviz.data.synthetic.elementwise import fundamental
from fviz.data.synthetic.raster import plane_coefficients, render_views
from fviz.data.synthetic.scene import sample_scenes
from fviz.errors import FvizError

MAX_GRAPHS = 4  # CUDA graphs kept (least recently used dropped first)
CUDA_GRAPHS = os.environ.get("FVIZ_SYNTHETIC_CUDA_GRAPHS", "1").strip() not in ("0", "false", "no", "off")
SIDE_STREAM = os.environ.get("FVIZ_SYNTHETIC_SIDE_STREAM", "1").strip() not in ("0", "false", "no", "off")


def seed_list(seeds: Sequence[int] | torch.Tensor) -> list[int]:
    """Seeds as Python ints, each checked to be in [0, 2**63)."""
    seeds = seeds.tolist() if isinstance(seeds, torch.Tensor) else list(seeds)
    ok = (isinstance(s, numbers.Integral) and not isinstance(s, bool) and 0 <= s < 2**63 for s in seeds)
    if not seeds or not all(ok):
        raise FvizError(f"seeds: must be a non-empty sequence of integers in [0, 2**63) (got {seeds!r})")
    return [int(s) for s in seeds]


def _seed_tensor(seeds: Sequence[int] | torch.Tensor, device: torch.device) -> torch.Tensor:
    """Seeds as int64 (B,) on ``device``, without a blocking copy.

    Seeds already on a GPU are taken as they are (checking their values would need a host sync).
    """
    if isinstance(seeds, torch.Tensor) and seeds.device.type != "cpu":
        if seeds.dim() != 1 or not seeds.numel() or seeds.dtype.is_floating_point or seeds.dtype.is_complex or seeds.dtype == torch.bool:
            raise FvizError(f"seeds: must be a non-empty 1-D integer tensor (got {seeds.dtype} {tuple(seeds.shape)})")
        return seeds.to(device, torch.int64, non_blocking=True)
    t = torch.tensor(seed_list(seeds), dtype=torch.int64)
    if device.type == "cuda":
        return t.pin_memory().to(device, non_blocking=True)
    return t.to(device)


@torch.no_grad()
def generate(seeds: torch.Tensor, cfg: SceneConfig, c: SceneConsts, with_depth: bool, internals: bool = False) -> dict:
    """render_batch on tensors: seeds (B,) int64 on the device of ``c``; no host sync on a GPU."""
    with torch.autocast(seeds.device.type, enabled=False):  # float64 geometry, float32 pixels, whatever the caller's
        return _generate_fp(seeds, cfg, c, with_depth, internals)


def _generate_fp(seeds: torch.Tensor, cfg: SceneConfig, c: SceneConsts, with_depth: bool, internals: bool) -> dict:
    B, H, W = seeds.shape[0], cfg.height, cfg.width
    sc = sample_scenes(seeds, cfg, c)
    coef, shade, valid = plane_coefficients(sc["planes"], sc["R_cw"], sc["C"], c.kinv)
    img, inv_z = render_views(coef, shade, valid, sc["sky"], H, W, c)
    if cfg.exposure > 0:
        img = img * sc["gain"].to(img.dtype)[:, None, None, None]
    if cfg.blur_sigma > 0:
        img = blur(img, cfg.blur_sigma)
    if cfg.noise_sigma > 0:  # per view from its own index into the bank: the same noise in any batch
        img = add_noise(img, sc["noise_mul"], sc["noise_add"], c.noise, c.pix)
    img.clamp_(0.0, 1.0).mul_(255.0).round_().div_(255.0)  # exactly the uint8 levels
    K = c.K.expand(B, 3, 3)
    out = {"image_a": img[:B], "image_b": img[B:], "F": fundamental(sc["R"], sc["t"], c.K_inv)}
    out |= {"K_a": K.clone(), "K_b": K.clone(), "R": sc["R"].contiguous(), "t": sc["t"]}
    if with_depth:
        depth = torch.where(inv_z > 0, 1.0 / inv_z, math.inf)
        out |= {"depth_a": depth[:B], "depth_b": depth[B:]}
    if internals:
        out |= {"coef": coef, "valid": valid}
    return out


class _Graph:
    """render_batch for one (config, device, stream, batch size, with_depth) as a replayed CUDA graph."""

    def __init__(self, cfg: SceneConfig, device: torch.device, batch: int, with_depth: bool) -> None:
        c = scene_consts(cfg, device)
        self.seeds = torch.zeros(batch, dtype=torch.int64, device=device)
        side = torch.cuda.Stream(device)
        side.wait_stream(torch.cuda.current_stream(device))
        with torch.cuda.stream(side):  # warm up outside the capture (allocator, lazy inits)
            for _ in range(2):
                generate(self.seeds, cfg, c, with_depth)
        torch.cuda.current_stream(device).wait_stream(side)
        self.graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(self.graph):
            self.out = generate(self.seeds, cfg, c, with_depth)

    def __call__(self, seeds: torch.Tensor) -> dict[str, torch.Tensor]:
        self.seeds.copy_(seeds)
        self.graph.replay()
        return {k: v.clone() for k, v in self.out.items()}  # the graph's buffers are reused next time


_GRAPHS: OrderedDict = OrderedDict()
_GRAPH_LOCK = threading.Lock()
_GRAPH_FAILED: set = set()


def _render_here(seeds: torch.Tensor, cfg: SceneConfig, device: torch.device, with_depth: bool) -> dict:
    """Render on the current stream: replay (capture the first time) the CUDA graph of this shape."""
    if CUDA_GRAPHS:
        key = (cfg, device, torch.cuda.current_stream(device).stream_id, seeds.shape[0], with_depth)
        with _GRAPH_LOCK:
            graph = _GRAPHS.get(key)
            if graph is None and key not in _GRAPH_FAILED:
                try:
                    graph = _Graph(cfg, device, seeds.shape[0], with_depth)
                except Exception as exc:  # noqa: BLE001 - any capture failure: run eagerly instead
                    _GRAPH_FAILED.add(key)
                    warnings.warn(f"fviz.data.synthetic: CUDA graph capture failed, rendering eagerly ({exc})", stacklevel=4)
                else:
                    _GRAPHS[key] = graph
                    while len(_GRAPHS) > MAX_GRAPHS:
                        _GRAPHS.popitem(last=False)
            if graph is not None:
                _GRAPHS.move_to_end(key)
                return graph(seeds)
    return generate(seeds, cfg, scene_consts(cfg, device), with_depth)


_SIDE_STREAMS: dict = {}


def _render_cuda(seeds: Sequence[int] | torch.Tensor, cfg: SceneConfig, device: torch.device, with_depth: bool) -> dict:
    """Render on a side stream of our own, which need not wait for the work the caller has queued
    (a training step, say), so the GPU can run both at once; the caller's stream then waits for
    the render, so its later work sees the results.  Seeds given as a list need no wait at all."""
    if not SIDE_STREAM:
        return _render_here(_seed_tensor(seeds, device), cfg, device, with_depth)
    caller = torch.cuda.current_stream(device)
    with _GRAPH_LOCK:
        side = _SIDE_STREAMS.get(device) or _SIDE_STREAMS.setdefault(device, torch.cuda.Stream(device))
    if isinstance(seeds, torch.Tensor) and seeds.device.type != "cpu":
        side.wait_stream(caller)  # the seeds may still be being written there
    with torch.cuda.stream(side):
        out = _render_here(_seed_tensor(seeds, device), cfg, device, with_depth)
    caller.wait_stream(side)
    for v in out.values():
        v.record_stream(caller)  # made on the side stream, used on the caller's: no early reuse of the memory
    return out


def render_batch(
    seeds: Sequence[int] | torch.Tensor,
    config: SceneConfig | None = None,
    device: str | torch.device = "cpu",
    with_depth: bool = False,
) -> dict[str, torch.Tensor]:
    """Render a batch of synthetic pairs, one per seed, on ``device``.

    Returns image_a, image_b (B, 1, H, W) float32 in [0, 1] (uint8 levels / 255), F (B, 3, 3)
    float64 (unit Frobenius norm, 'fbn' sign), K_a, K_b (B, 3, 3), R (B, 3, 3), t (B, 3) float64;
    with ``with_depth`` also depth_a, depth_b (B, 1, H, W) float32 (z in metres, inf for sky).
    The images of seed s are pixel-identical to ``synthetic_pair(s, config)``'s (on the CPU).
    On a CUDA device the call only queues work (no host sync): seeds given as a list are sent
    through pinned memory, seeds already on the GPU are used as they are (values unchecked).
    """
    cfg = canonical(config or SceneConfig())
    device = torch.device(device)
    if device.type == "cuda" and device.index is None:
        device = torch.device("cuda", torch.cuda.current_device())
    if device.type == "cuda":
        with torch.cuda.device(device):
            return _render_cuda(seeds, cfg, device, with_depth)
    return generate(_seed_tensor(seeds, device), cfg, scene_consts(cfg, device), with_depth)
