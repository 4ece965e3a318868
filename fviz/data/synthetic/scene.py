"""The street scenes and camera pairs of a batch of seeds, as batched tensor code on the rendering device.

A scene is piecewise planar: a road, building facades on both sides (a few segments per side joined by short walls),
a wall closing the street far ahead, and axis-aligned boxes and cars (a car is a body box plus a cabin box), each a
bounded rectangle.  Every parameter is a draw of :mod:`fviz.data.synthetic.draws`; the maths uses only + - * / sqrt
(:mod:`fviz.data.synthetic.elementwise`), one elementwise op at a time, so a scene is bit-identical on any device and
for any batch size.  A box slot that found no free spot, or the cabin slot of a crate, is an invalid plane.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import torch

from fviz.data.synthetic.appearance import NOISE_BANK_BITS
from fviz.data.synthetic.config import SceneConfig
from fviz.data.synthetic.consts import SceneConsts
from fviz.data.synthetic.draws import PLACEMENT_TRIES, SCENE_SALT, mix64, shr
from fviz.data.synthetic.elementwise import mm, mv, rotation, sincos

Draw = Callable[[str], torch.Tensor]  # a scene parameter's draws by name -> (B, *shape)


def sample_scenes(seeds: torch.Tensor, cfg: SceneConfig, c: SceneConsts) -> dict[str, torch.Tensor]:
    """Draw the street scenes and camera pairs of ``seeds`` (B,) int64, on their device, float64.

    Returns planes (2 B, P, 20): per view (all a's, then all b's) the P rectangles it needs, as
    origin (3), e1 (3), e2 (3) (street frame), size (2), texture map (2 x 3: plane coordinates
    (s, r, 1) in metres -> grid_sample coordinates), shade (gain, brightness) and valid (0 / 1);
    R_cw (2 B, 3, 3), C (2 B, 3): the cameras; sky (2 B,); noise_mul, noise_add (2 B,) int32: the
    affine noise index of each view (see noise_bank); R (B, 3, 3), t (B, 3): the motion a -> b.
    """
    B = seeds.shape[0]
    bits = mix64(mix64(seeds + SCENE_SALT)[:, None] + c.steps)  # (B, D): splitmix64 stream of each seed
    u = c.lo + c.span * (shr(bits, 11).to(torch.float64) * 2.0**-53)  # uniform in [lo, hi)
    g = functools.partial(c.layout.get, u)
    h = g("h")[:, None]
    street, dist = _street(g, h, cfg, c)
    geo = [street]
    ok = [torch.ones(B, 4 * cfg.facade_segments, dtype=torch.bool, device=u.device)]
    box_hi = None
    if cfg.n_boxes:  # cars (body + cabin) and crates (body + invalid cabin slot) that do not overlap
        faces, placed, box_hi = _boxes(g, h, dist, cfg, c)
        geo.append(faces)
        ok.append(placed)
    geo = torch.cat(geo, 1)  # (B, Rt, 5)
    valid = torch.cat(ok, 1) & (geo[..., 3] > 1e-3) & (geo[..., 4] > 1e-3)
    tex = g("tex")  # (B, Rt, 6)
    tmap, R, t, R_cw, C = _texture_maps_and_cameras(g, tex, cfg, c)
    planes = _planes_per_view(geo, valid, tmap, tex, C, box_hi, cfg, c)
    keys = shr(c.layout.get(bits, "noise"), 20).t()  # (2, B) 44 bits per view
    mask = (1 << NOISE_BANK_BITS) - 1
    return {
        "planes": planes,
        "R_cw": R_cw.reshape(2 * B, 3, 3),
        "C": C.reshape(2 * B, 3),
        "sky": g("sky").repeat(2),
        "gain": (1.0 + cfg.exposure * g("exposure")).t().reshape(2 * B),  # views a (first B), then b
        "noise_mul": ((keys & mask) | 1).reshape(2 * B).to(torch.int32),
        "noise_add": (shr(keys, NOISE_BANK_BITS) & mask).reshape(2 * B).to(torch.int32),
        "R": R,
        "t": t,
    }


def _street(g: Draw, h: torch.Tensor, cfg: SceneConfig, c: SceneConsts) -> tuple[torch.Tensor, torch.Tensor]:
    """Facades of both sides (segments and junction walls), road, end wall: the 4 n fixed rectangles.

    h (B, 1): the camera height (the road is the plane y = h).  Returns the rectangles (B, 4 n, 5) as origin (3) and
    size (2), in slot order, and the facades' lateral distances dist (B, 2, n) (left, right).
    """
    B, n = h.shape[0], cfg.facade_segments
    far = g("far")[:, None]
    z = [torch.full_like(far, -6.0), far]
    if n > 1:
        z.insert(1, (5.0 + (far - 15.0) * g("cuts")).sort(-1).values)
    z = torch.cat(z, 1)  # (B, n + 1) segment ends along the street
    dist = g("base")[..., None] + g("dist")  # (B, 2, n) lateral distance (left, right)
    tall = g("tall")
    x = c.side * dist  # signed x of each segment
    hh = h[..., None]
    fac = torch.stack([x, hh - tall, z[:, None, :-1].expand(B, 2, n), (z[:, 1:] - z[:, :-1])[:, None].expand(B, 2, n), tall], -1)
    # junction walls: the end of the building that sticks out further into the street
    xa, xb = x[..., :-1], x[..., 1:]
    jh = torch.where(dist[..., :-1] < dist[..., 1:], tall[..., :-1], tall[..., 1:])
    jun = torch.stack([torch.minimum(xa, xb), hh - jh, z[:, None, 1:-1].expand(B, 2, n - 1), (xa - xb).abs(), jh], -1)
    dl, dr = dist[:, 0], dist[:, 1]
    wl, wr, end_h = dl.amax(-1, keepdim=True), dr.amax(-1, keepdim=True), g("end_h")[:, None]
    road = torch.cat([-wl, h, z[:, :1], wl + wr, far + 6.0], 1)
    end = torch.cat([-dl[:, -1:], h - end_h, far, dl[:, -1:] + dr[:, -1:], end_h], 1)
    return torch.cat([torch.cat([fac, jun], 2).reshape(B, 4 * n - 2, 5), road[:, None], end[:, None]], 1), dist


def _boxes(
    g: Draw, h: torch.Tensor, dist: torch.Tensor, cfg: SceneConfig, c: SceneConsts
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The 5 faces (x0, x1, z0, z1, top) of each box: body, cabin, body, cabin, ... of the n_boxes cars and crates.

    h (B, 1): the camera height; dist (B, 2, n): the facades' lateral distances.  Returns the rectangles
    (B, 10 n_boxes, 5) as origin (3) and size (2), which exist (B, 10 n_boxes) bool, and the boxes' far corners
    (B, 2 n_boxes, 3).
    """
    B, nb = h.shape[0], cfg.n_boxes
    dl, dr = dist[:, 0], dist[:, 1]
    xl, xr = 0.3 - dl.amin(-1, keepdim=True), dr.amin(-1, keepdim=True) - 0.3  # (B, 1) free width
    car = g("car") < 0.6
    w, l, bh = torch.where(car[..., None], g("car_dims"), g("crate_dims")).unbind(-1)  # (B, nb)
    foot, placed = _place_boxes(g, xl, xr, w, l, cfg, c)
    x0, x1, z0, z1 = foot.unbind(-1)
    cu = g("cabin")
    cw, cl, top = w - cu[..., 0], l * cu[..., 1], h - bh
    cx0, cz0 = x0 + (w - cw) * 0.5, z0 + l * cu[..., 3]
    lo = torch.stack([torch.stack([x0, top, z0], -1), torch.stack([cx0, top - cu[..., 2], cz0], -1)], 2)
    hi = torch.stack([torch.stack([x1, h.expand(B, nb), z1], -1), torch.stack([cx0 + cw, top, cz0 + cl], -1)], 2)
    lo, hi = lo.reshape(B, 2 * nb, 3), hi.reshape(B, 2 * nb, 3)  # body, cabin, body, cabin, ...
    bx0, by0, bz0 = lo.unbind(-1)
    bx1, by1, bz1 = hi.unbind(-1)
    bw, bt, bl = bx1 - bx0, by1 - by0, bz1 - bz0
    faces = torch.stack([
        torch.stack([bx0, bx1, bx0, bx0, bx0], -1),
        by0[..., None].expand(B, 2 * nb, 5),
        torch.stack([bz0, bz0, bz0, bz1, bz0], -1),
        torch.stack([bl, bl, bw, bw, bw], -1),
        torch.stack([bt, bt, bt, bt, bl], -1),
    ], -1)  # fmt: skip
    ok = torch.stack([placed, placed & car], -1)[..., None].expand(B, nb, 2, 5).reshape(B, 10 * nb)
    return faces.reshape(B, 10 * nb, 5), ok, hi


def _place_boxes(
    g: Draw, xl: torch.Tensor, xr: torch.Tensor, w: torch.Tensor, l: torch.Tensor, cfg: SceneConfig, c: SceneConsts
) -> tuple[torch.Tensor, torch.Tensor]:
    """Rejection sampling of the boxes' spots: each box takes the first of its tries that fits in the free width
    [xl, xr] (B, 1) and stays 0.3 m clear of the boxes placed before it.

    w, l (B, nb): the boxes' widths and lengths.  Returns the footprints (B, nb, 4) as x0, x1, z0, z1 and whether
    each box found a spot (B, nb) bool.
    """
    B, nb, T = w.shape[0], cfg.n_boxes, PLACEMENT_TRIES
    z_min = cfg.forward_range[1] + 2.0
    x0c = xl[..., None] + (xr[..., None] - w[..., None] - xl[..., None]) * g("try_x")  # (B, nb, T)
    z0c = g("try_z")
    fits = (xl[..., None] <= x0c) & (x0c + w[..., None] <= xr[..., None])
    foot = w.new_zeros(B, nb, 4)  # x0, x1, z0, z1 of the boxes placed so far
    placed = torch.zeros(B, nb, dtype=torch.bool, device=w.device)
    for j in range(nb):  # rejection sampling: the first try clear of the boxes before
        xj, zj, wj, lj = x0c[:, j], z0c[:, j], w[:, j : j + 1], l[:, j : j + 1]
        free = fits[:, j]
        if j:
            f = foot[:, None, :j]  # (B, 1, j, 4)
            apart = (
                (xj[..., None] > f[..., 1] + 0.3)
                | ((xj + wj)[..., None] < f[..., 0] - 0.3)
                | (zj[..., None] > f[..., 3] + 0.3)
                | ((zj + lj)[..., None] < f[..., 2] - 0.3)
                | ~placed[:, None, :j]
            )
            free = free & apart.all(-1)
        first = torch.where(free, c.tries, T).amin(-1, keepdim=True)  # (B, 1), T: no free try
        found = first < T
        sel = first.clamp(max=T - 1)
        x0 = torch.where(found, xj.gather(1, sel), 0.0)
        z0 = torch.where(found, zj.gather(1, sel), z_min)
        foot[:, j] = torch.cat([x0, x0 + wj, z0, z0 + lj], 1)
        placed[:, j] = found[:, 0]
    return foot, placed


def _texture_maps_and_cameras(
    g: Draw, tex: torch.Tensor, cfg: SceneConfig, c: SceneConsts
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The planes' texture maps, the camera mount and the motion a -> b, all angles in one sincos.

    tex (B, Rt, 6): each plane's texture draws (scale, angle, offset x, offset y, gain, brightness).  Returns tmap
    (B, Rt, 6): rows (c, -s, ox), (s, c, oy) of each plane; R (B, 3, 3), t (B, 3): X_b = R X_a + t; R_cw (2, B, 3, 3),
    C (2, B, 3): cameras a and b in the street frame (X_cam = R_cw (X - C)).
    """
    B, Rt = tex.shape[:2]
    motion = g("motion")
    if cfg.straight_fraction > 0:
        motion = motion * torch.where(g("straight") < cfg.straight_fraction, 0.1, 1.0)[:, None]
    sin, cos = sincos(torch.cat([tex[..., 1], g("mount"), motion, motion[:, :1] * 0.5], 1))
    scale = c.kscale / tex[..., 0]
    st, ct = sin[:, :Rt] * scale, cos[:, :Rt] * scale
    tmap = torch.stack([ct, -st, tex[..., 2], st, ct, tex[..., 3]], -1)  # rows (c, -s, ox), (s, c, oy)
    rot = rotation(sin[:, Rt : Rt + 6].reshape(B, 2, 3), cos[:, Rt : Rt + 6].reshape(B, 2, 3))
    R_aw = rot[:, 0]  # camera mount
    if cfg.stereo:
        Q = c.eye.expand(B, 3, 3)
        zero = tex.new_zeros(B)
        c_b = torch.stack([zero + cfg.baseline, zero, zero], -1)
    else:  # car-like: drive forward along an arc (translation at half the yaw), small pitch and roll
        Q = rot[:, 1]
        fwd = g("fwd")
        c_b = torch.stack([fwd * sin[:, -1], fwd * g("lift"), fwd * cos[:, -1]], -1)
    R = Q.transpose(1, 2)  # X_b = Q^T (X_a - c_b), with Q the axes and c_b the centre of b in frame a
    t = -mv(R, c_b)
    R_cw = torch.stack([R_aw, mm(R, R_aw)])  # (2, B, 3, 3)
    C = torch.stack([torch.zeros_like(c_b), mv(R_aw.transpose(1, 2), c_b)])  # (2, B, 3)
    return tmap, R, t, R_cw, C


def _planes_per_view(
    geo: torch.Tensor,
    valid: torch.Tensor,
    tmap: torch.Tensor,
    tex: torch.Tensor,
    C: torch.Tensor,
    box_hi: torch.Tensor | None,
    cfg: SceneConfig,
    c: SceneConsts,
) -> torch.Tensor:
    """The planes each view needs: the fixed ones and the 3 faces of each box towards its camera.  -> (2 B, P, 20).

    geo (B, Rt, 5), valid (B, Rt), tmap (B, Rt, 6), tex (B, Rt, 6), C (2, B, 3), box_hi (B, 2 n_boxes, 3) or None.
    """
    B, Rt = tex.shape[:2]
    n, nb = cfg.facade_segments, cfg.n_boxes
    fields = torch.cat(
        [geo[..., :3], c.e1.expand(B, Rt, 3), c.e2.expand(B, Rt, 3), geo[..., 3:], tmap, tex[..., 4:], valid[..., None].to(torch.float64)],
        -1,
    )  # (B, Rt, 20)
    idx = c.fixed_idx.expand(2, B, 4 * n)
    if nb:
        face = torch.stack([
            c.box_x + (C[..., 0:1] > box_hi[..., 0]),
            c.box_z + (C[..., 2:3] > box_hi[..., 2]),
            c.box_top.expand(2, B, 2 * nb),
        ], -1)  # fmt: skip
        idx = torch.cat([idx, face.reshape(2, B, 6 * nb)], -1)
    P = idx.shape[-1]
    return fields.expand(2, B, Rt, 20).gather(2, idx[..., None].expand(2, B, P, 20)).reshape(2 * B, P, 20)
