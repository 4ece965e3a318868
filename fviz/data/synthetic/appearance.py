"""What the pixels get besides geometry: the shared surface texture (a bank every plane samples with its own scale,
rotation and offset), the camera's blur, and pixel noise read from a fixed bank of Gaussian values at a per-view
pseudo-random affine index."""

from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as tnf

TEXTURE_SIZE = 1024  # texels per side of the shared texture bank
NOISE_BANK_BITS = 19  # pixel-noise bank: 2**19 standard normal values (2 MB: cache-sized; > 1242 x 375 pixels)


@functools.lru_cache(maxsize=4)
def texture_bank(device: str = "cpu") -> torch.Tensor:
    """The shared surface texture: 1/f noise plus random blocks, zero mean, unit std.  -> (1, 1, T, T).

    Generated once per process (on the CPU, from a fixed seed, then moved to ``device``); planes
    sample it with reflection padding, so it tiles without seams.
    """
    n = TEXTURE_SIZE
    g = torch.Generator().manual_seed(20180312)
    fy, fx = torch.fft.fftfreq(n, dtype=torch.float64)[:, None], torch.fft.rfftfreq(n, dtype=torch.float64)[None]
    amp = (fx**2 + fy**2).clamp_min(1.0 / n**2) ** -0.35  # amplitude ~ f^-0.7: detail at all scales
    noise = torch.fft.irfft2(torch.fft.rfft2(torch.randn(n, n, generator=g, dtype=torch.float64)) * amp, s=(n, n))
    blocks = torch.zeros(n, n, dtype=torch.float64)
    for x0, y0, lw, lh, v in torch.rand(1500, 5, generator=g, dtype=torch.float64).tolist():
        w, h = int(3 * 20 ** lw), int(3 * 20 ** lh)  # 3 .. 60 texels
        x0, y0 = int(x0 * (n - w)), int(y0 * (n - h))
        blocks[y0 : y0 + h, x0 : x0 + w] += 2.0 * v - 1.0
    bank = noise / noise.std() + 0.8 * blocks / blocks.std()
    bank = ((bank - bank.mean()) / bank.std()).clamp(-3.0, 3.0)
    return bank.float().to(device)[None, None].contiguous()


@functools.lru_cache(maxsize=4)
def noise_bank(device: str = "cpu") -> torch.Tensor:
    """2**NOISE_BANK_BITS standard normal float32 values (fixed seed, made on the CPU).  -> (2**bits,).

    View k reads pixel p's noise at index (a_k p + b_k) mod 2**bits, a_k odd: a per-view
    permutation of the bank, so the noise of any two views (a and b of a pair too) is unrelated
    (it repeats within a view only in images of more than 2**bits pixels).
    """
    g = torch.Generator().manual_seed(0x0DDBA11)
    return torch.randn(1 << NOISE_BANK_BITS, generator=g).to(device)


def blur(img: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur with reflected borders, as shifted sums (exact per sample).  (N, 1, H, W)."""
    r = max(1, math.ceil(3.0 * sigma))
    k = [math.exp(-0.5 * (i / sigma) ** 2) for i in range(-r, r + 1)]
    k = [x / sum(k) for x in k]
    H, W = img.shape[-2:]
    out, tmp = torch.zeros_like(img), torch.empty_like(img)
    x = tnf.pad(img, (r, r, 0, 0), mode="reflect")
    for i, ki in enumerate(k):
        out.add_(torch.mul(x[..., i : i + W], ki, out=tmp))
    x = tnf.pad(out, (0, 0, r, r), mode="reflect")
    out.zero_()
    for i, ki in enumerate(k):
        out.add_(torch.mul(x[..., i : i + H, :], ki, out=tmp))
    return out


def add_noise(img: torch.Tensor, a: torch.Tensor, b: torch.Tensor, bank: torch.Tensor, pix: torch.Tensor) -> torch.Tensor:
    """img (N, 1, H, W) += bank[(a p + b) mod len(bank)] for pixel p (pix: 0 .. H W - 1, int32) of view n, in place."""
    N, _, H, W = img.shape
    idx = pix * a[:, None]  # int32 wraps: mod 2**32
    idx = idx.add_(b[:, None]).bitwise_and_(bank.shape[0] - 1)
    return img.add_(bank.index_select(0, idx.view(-1)).view(N, 1, H, W))
