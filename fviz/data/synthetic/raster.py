"""Exact ray casting of piecewise-planar views, vectorised in torch.

For a plane, 1/depth and the four "ray inside edge k" tests are affine functions of the pixel (u, v)
(:func:`plane_coefficients`), so along one image row each plane covers one interval of u.  Because the rectangles of
a scene never cross (they may only touch along edges), the nearest plane along a row can only change at an interval
end: the renderer sorts the interval ends of a row, finds the nearest plane at the middle of each piece (rows x pieces
x planes, cheap) and spreads the winner over the pixels of the piece.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as tnf

from fviz.data.synthetic.appearance import texture_bank
from fviz.data.synthetic.consts import SceneConsts
from fviz.data.synthetic.elementwise import cross, dot, mv

CHUNK_PIXELS = 1 << 17  # pixels shaded per step on the CPU (keeps the work buffers in cache)
GPU_CHUNK_PIXELS = 1 << 23  # pixels shaded per step on a GPU (bounds the work buffers)


def plane_coefficients(
    planes: torch.Tensor, R_cw: torch.Tensor, C: torch.Tensor, kinv: tuple[float, float, float, float]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per-plane affine functions of the pixel, for N views.

    planes (N, P, 20) (see sample_scenes), R_cw (N, 3, 3), C (N, 3), kinv = (1/fx, -cx/fx, 1/fy, -cy/fy).
    Returns coef (N, P, 7, 3) float64, shade (N, P, 2), valid (N, P).  Row k of coef is (a, b, c)
    with value a u + b v + c at pixel (u, v): rows 0-3 are >= 0 iff the ray is inside edge k of the
    rectangle (the cone over a convex polygon), row 4 is 1/depth (z), rows 5-6 are the grid_sample
    texture coordinates times 1/depth.
    """
    Rm = R_cw[:, None]
    o = mv(Rm, planes[..., 0:3] - C[:, None])  # (N, P, 3) in camera coordinates
    e1, e2 = mv(Rm, planes[..., 3:6]), mv(Rm, planes[..., 6:9])
    s1, s2 = e1 * planes[..., 9:10], e2 * planes[..., 10:11]
    c1 = o + s1
    corners = torch.stack([o, c1, c1 + s2, o + s2], -2)  # (N, P, 4, 3)
    edges = cross(corners, corners.roll(-1, -2))  # planes through the centre and an edge
    centre = o + 0.5 * (s1 + s2)
    edges = edges * dot(edges, centre[..., None, :]).sign()[..., None]  # interior on the + side
    nrm = cross(e1, e2)
    d = dot(nrm, o)  # plane nrm . X = d
    valid = (planes[..., 19] > 0) & (d.abs() > 1e-9)
    inv_depth = nrm / torch.where(valid, d, 1.0)[..., None]  # 1/z = (nrm / d) . ray  for ray = K^-1 (u, v, 1)
    q1 = e1 - dot(e1, o)[..., None] * inv_depth  # plane coordinate s times 1/z
    q2 = e2 - dot(e2, o)[..., None] * inv_depth
    tm = planes[..., 11:17, None]  # (N, P, 6, 1)
    tex_num = tm[..., 0::3, :] * q1[..., None, :] + tm[..., 1::3, :] * q2[..., None, :] + tm[..., 2::3, :] * inv_depth[..., None, :]
    a, b, cc = torch.cat([edges, inv_depth[..., None, :], tex_num], -2).unbind(-1)  # (N, P, 7) on rays
    coef = torch.stack([a * kinv[0], b * kinv[2], a * kinv[1] + b * kinv[3] + cc], -1)  # on pixels
    return torch.where(valid[..., None, None], coef, 0.0), planes[..., 17:19], valid


def _row_intervals(
    alpha: torch.Tensor, delta: torch.Tensor, valid: torch.Tensor, width: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per row, the pixels u (integers) where a ray is inside all 4 edges of a rectangle.

    alpha (N, 1, P, 4), delta (N, H, P, 4): edge k holds where alpha u + delta >= 0.  valid (N, P).
    Returns kl, kh (N, H, P) int16: the pixels kl <= u < kh, in [0, width]; empty: kl = width, kh = 0.
    """
    cut = -delta / alpha  # inf / nan where alpha == 0: masked below
    lo = torch.where(alpha > 0, cut, -math.inf).amax(-1).clamp_(-1, width)
    hi = torch.where(alpha < 0, cut, math.inf).amin(-1).clamp_(-1, width)
    empty = ((alpha == 0) & (delta < 0)).any(-1) | (lo >= hi) | ~valid[:, None]
    lo, hi = lo.masked_fill_(empty, float(width)), hi.masked_fill_(empty, -1.0)
    return lo.ceil_().clamp_(0, width).to(torch.int16), hi.ceil_().clamp_(0, width).to(torch.int16)


def _pieces(
    kl: torch.Tensor, kh: torch.Tensor, a_w: torch.Tensor, d_w: torch.Tensor, width: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Cut each row where any plane starts or ends and find the nearest plane on each piece.

    kl, kh (N, H, P) int16 pixel ranges [kl, kh); a_w (N, 1, P), d_w (N, H, P): 1/z = a_w u + d_w.
    Returns the sorted piece starts (N, H, S + 1) int16 (pixels start <= u < next start) and the
    nearest plane of each piece (N, H, S), P where no plane is hit; S = 2 P + 1.  Which planes
    cover a pixel is constant on a piece, and planes never cross, so the nearest one is too: it is
    found at the piece's first pixel (float32: planes differ there by far more than its rounding).
    """
    N, H, P = kl.shape
    edge = kl.new_zeros((N, H, 1))
    starts = torch.cat([kl, kh, edge, edge + width], -1).sort(-1).values
    u = starts[..., :-1, None]  # (N, H, S, 1) first pixel of each piece
    inv_z = (a_w.float()[:, :, None] * u).add_(d_w.float()[:, :, None])  # (N, H, S, P)
    inv_z.masked_fill_((u < kl[:, :, None]) | (u >= kh[:, :, None]), -math.inf)
    best, idx = inv_z.max(-1)
    return starts, idx.masked_fill_(best == -math.inf, P)


def _piece_table(
    alpha: torch.Tensor, delta: torch.Tensor, shade: torch.Tensor, sky: torch.Tensor, idx: torch.Tensor
) -> torch.Tensor:
    """What the pixels of each piece need, as affine functions of u: (8, N H S) float32.

    Rows: tex x (slope, offset), tex y (slope, offset), 1/z (slope, offset), gain, brightness.
    The sky piece has 1/z = -1 (negative marks "nothing hit"), gain 0 and the sky brightness.
    alpha (N, 1, P, 7), delta (N, H, P, 7), shade (N, P, 2), sky (N,), idx (N, H, S).
    """
    N, H, P = delta.shape[:3]
    parts = []
    for k in (5, 6, 4):
        parts += [alpha[..., k].expand(N, H, P), delta[..., k]]
    parts += [shade[:, None, :, 0].expand(N, H, P), shade[:, None, :, 1].expand(N, H, P)]
    sky_part = delta.new_zeros(8, N, H, 1)
    sky_part[5], sky_part[7] = -1.0, sky[:, None, None]
    table = torch.cat([torch.stack(parts), sky_part], -1).float()  # (8, N, H, P + 1)
    return table.gather(-1, idx.expand(8, -1, -1, -1)).reshape(8, -1)


def _shade(table: torch.Tensor, starts: torch.Tensor, img: torch.Tensor, inv_z: torch.Tensor, chunk_rows: int) -> None:
    """Fill img and inv_z (N H, W) float32: texture lookups of the nearest plane of every pixel.

    Pixel u of a row lies in the piece with start <= u < next start (starts (N, H, S + 1), sorted).
    Works on chunks of rows with reused buffers (fresh CPU allocations page-fault, which costs
    more than the maths).
    """
    W, S = img.shape[1], starts.shape[-1] - 1
    starts = starts.long()
    counts = (starts[..., 1:] - starts[..., :-1]).reshape(-1)  # (N H S,), W per row
    first = torch.cumsum(counts, 0) - counts  # first pixel of each piece
    filled = counts > 0
    u = torch.arange(W, dtype=torch.float32, device=img.device)
    bank = texture_bank(str(img.device))
    rows = img.shape[0]
    chunk_rows = min(chunk_rows, rows)
    cols_buf = img.new_empty(8 * chunk_rows * W)
    mark_buf = torch.empty(chunk_rows * W, dtype=torch.int32, device=img.device)
    grid_buf = img.new_empty(2, chunk_rows, W)  # x, y planes: contiguous writes; grid_sample takes the permuted view
    for r0 in range(0, rows, chunk_rows):
        r1 = min(rows, r0 + chunk_rows)
        n = (r1 - r0) * W
        k = torch.nonzero(filled[r0 * S : r1 * S]).squeeze(1) + r0 * S  # pieces with pixels here
        mark = mark_buf[:n].zero_()
        mark[first[k] - r0 * W] = torch.diff(k, prepend=k.new_zeros(1)).int()  # piece index steps
        piece = torch.cumsum(mark, 0, dtype=torch.int32)
        cols = torch.index_select(table, 1, piece, out=cols_buf[: 8 * n].view(8, n)).view(8, r1 - r0, W)
        z = torch.mul(cols[4], u, out=inv_z[r0:r1]).add_(cols[5])
        grid = grid_buf[:, : r1 - r0]
        torch.mul(cols[0], u, out=grid[0]).add_(cols[1]).div_(z)
        torch.mul(cols[2], u, out=grid[1]).add_(cols[3]).div_(z)
        tex = tnf.grid_sample(bank, grid.permute(1, 2, 0)[None], mode="bilinear", padding_mode="reflection", align_corners=False)
        torch.mul(tex[0, 0], cols[6], out=img[r0:r1]).add_(cols[7])


def _shade_all(table: torch.Tensor, starts: torch.Tensor, img: torch.Tensor, inv_z: torch.Tensor, c: SceneConsts) -> None:
    """_shade without host synchronisation (GPU): every pixel finds its piece by binary search.

    table (8, N H S), starts (N, H, S + 1), img and inv_z (N H, W) filled in place.
    """
    rows, W = img.shape
    S = starts.shape[-1] - 1
    starts = starts.to(torch.int32).reshape(rows, S + 1)
    chunk = max(1, min(rows, GPU_CHUNK_PIXELS // W))
    u_rows = c.u_int.expand(chunk, W).contiguous()
    first = torch.arange(0, chunk * S, S, dtype=torch.int32, device=img.device)[:, None] - 1
    grid = img.new_empty(2, chunk, W)
    for r0 in range(0, rows, chunk):
        r1 = min(rows, r0 + chunk)
        n = r1 - r0
        piece = torch.searchsorted(starts[r0:r1], u_rows[:n], right=True, out_int32=True)  # 1 + piece in row
        piece += first[:n] + r0 * S
        cols = table.index_select(1, piece.view(-1)).view(8, n, W)
        z = torch.mul(cols[4], c.u, out=inv_z[r0:r1]).add_(cols[5])
        gr = grid[:, :n]
        torch.mul(cols[0], c.u, out=gr[0]).add_(cols[1]).div_(z)
        torch.mul(cols[2], c.u, out=gr[1]).add_(cols[3]).div_(z)
        tex = tnf.grid_sample(c.bank, gr.permute(1, 2, 0)[None], mode="bilinear", padding_mode="reflection", align_corners=False)
        torch.mul(tex[0, 0], cols[6], out=img[r0:r1]).add_(cols[7])


def render_views(
    coef: torch.Tensor,
    shade: torch.Tensor,
    valid: torch.Tensor,
    sky: torch.Tensor,
    height: int,
    width: int,
    c: SceneConsts,
    step: int | None = None,
    chunk_rows: int | None = None,
    sync_free: bool | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Ray-cast N views of piecewise-planar scenes whose rectangles never cross.

    coef (N, P, 7, 3) float64 (see plane_coefficients), shade (N, P, 2), valid (N, P), sky (N,).
    Returns the intensity (N, 1, H, W) float32 (not clamped) and 1/depth (N, 1, H, W) float32,
    negative where no plane is hit.  On the CPU views are done ``step`` at a time (default 1),
    pixels ``chunk_rows`` rows at a time (default CHUNK_PIXELS: cache-sized work), and only the
    planes some row sees take part (a host sync, cheap there).  On a GPU (or with ``sync_free``)
    all views at once with all planes, without host synchronisation: the same pixels.
    """
    N, H, W, dev = coef.shape[0], height, width, coef.device
    img = torch.empty(N * H, W, dtype=torch.float32, device=dev)
    inv_z = torch.empty_like(img)
    if sync_free is None:
        sync_free = dev.type != "cpu"
    if sync_free:
        alpha, delta = coef[:, None, :, :, 0], c.rows * coef[:, None, :, :, 1] + coef[:, None, :, :, 2]  # (N, 1|H, P, 7)
        kl, kh = _row_intervals(alpha[..., :4], delta[..., :4], valid, W)
        starts, idx = _pieces(kl, kh, alpha[..., 4], delta[..., 4], W)
        _shade_all(_piece_table(alpha, delta, shade, sky, idx), starts, img, inv_z, c)
        return img.view(N, 1, H, W), inv_z.view(N, 1, H, W)
    step = step or 1
    chunk_rows = chunk_rows or max(1, CHUNK_PIXELS // W)
    v = c.rows
    for i in range(0, N, step):
        cf = coef[i : i + step]
        alpha, delta = cf[:, None, :, :, 0], v * cf[:, None, :, :, 1] + cf[:, None, :, :, 2]  # (n, 1|H, P, 7)
        kl, kh = _row_intervals(alpha[..., :4], delta[..., :4], valid[i : i + step], W)
        seen = torch.nonzero((kl < kh).flatten(0, 1).any(0)).squeeze(1)  # planes in view: fewer pieces
        starts, idx = _pieces(kl[..., seen], kh[..., seen], alpha[..., seen, 4], delta[..., seen, 4], W)
        idx = torch.cat([seen, seen.new_full((1,), cf.shape[1])])[idx]  # back to plane numbers, P = sky
        table = _piece_table(alpha, delta, shade[i : i + step], sky[i : i + step], idx)
        rows = slice(i * H, min(N, i + step) * H)
        _shade(table, starts, img[rows], inv_z[rows], chunk_rows)
    return img.view(N, 1, H, W), inv_z.view(N, 1, H, W)

