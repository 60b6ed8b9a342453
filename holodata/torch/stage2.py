"""Learned stage two of HoloRadar (paper §4.4, appendix C.2): range images → 3-D points.

Numeric cores only (no I/O); the training loop and checkpoints live in
:mod:`holodata.torch.stage2_train`. Everything is in one frame's radar frame, metres.

Shapes: ``R`` (N,3,H,W) accumulated travel distance per bounce (NaN = none), ``origins``
(H,W,3) or (N,H,W,3) beam origins, ``directions`` (H,W,3) or (N,H,W,3) unit beam directions d_1.

* :func:`normals_from_range_t` — eq. 4 (the closed-form normal of a range image) in torch,
  the same finite-difference formulation as :func:`holodata.geometry.unmirror.normals_from_range`.
* :func:`ray_trace` — the three cascaded ray-tracing blocks, eq. 2 (reflect the direction at the
  previous normal) and eq. 3 (walk the segment ``R_b − R_{b−1}``), with the mirrored normals of
  each bounce un-mirrored through every earlier normal (eq. 5).
* :class:`HybridNormalBlock` — one hybrid estimation block: the analytic eq. 4/5 branch plus a
  residual CNN branch on range and previous-normal images, fused into a unit normal.
* :class:`RayTracer` — three hybrid blocks cascaded through :func:`ray_trace`; loss eq. 6.
* :class:`VoxelRefiner` — volumetric refinement: per-point features → voxel encoder (mean per
  voxel) → sparse 3-D UNet (scatter/gather convolutions on the occupied voxels, plain torch) →
  per-voxel class (empty / human / structure) + offset; loss eq. 7 with the EDT distance term.
  A refined voxel's LOS flag and human probability are the means over its input points
  (:func:`voxel_point_mean`): LOS is geometry (visible in the first-bounce image), not learned.
  At inference the refined cloud is the input points of the kept voxels
  (:meth:`holodata.torch.stage2_infer.Stage2.predict`); the offset head is a training target only.

Local beam frame: per pixel ``[d, e_φ, e_θ]`` with ``e_φ = normalize(ẑ × d)`` and
``e_θ = d × e_φ`` (the directions of increasing azimuth and elevation of a grid beam). The
geometry vector of eq. 4 is a normal's local components scaled so that its first one is 1:
``b = c / c_0`` with ``c = (n·d, n·e_φ, n·e_θ)`` of the normal pointing away from the sensor
(for ``p = R d``: ``b = [1, −∂R/∂φ /(R cosθ), −∂R/∂θ / R]``, eq. 4 with this frame's signs).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from holodata.conventions import DEFAULT_MAX_RANGE_M

# ----------------------------------------------------------------------------- analytic cores


def reflect(v: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
    """``v − 2 (v·n) n`` over the last axis (eq. 2 for directions, eq. 5 for normals)."""
    return v - 2.0 * (v * n).sum(-1, keepdim=True) * n


def _tangent(R: torch.Tensor, P: torch.Tensor, axis: int, periodic: bool) -> torch.Tensor:
    """Tangent (…,H,W,3) of the point image P along grid ``axis`` (-2 rows, -1 columns): of the
    forward and backward neighbour differences, the one with the smaller range jump."""
    pax = axis - 1
    nan = float("nan")
    if periodic:
        fwd_r, bwd_r = torch.roll(R, -1, axis) - R, R - torch.roll(R, 1, axis)
        fwd_p, bwd_p = torch.roll(P, -1, pax) - P, P - torch.roll(P, 1, pax)
    else:
        dr, dp = torch.diff(R, dim=axis), torch.diff(P, dim=pax)
        pad_r = torch.full_like(R.narrow(axis, 0, 1), nan)
        pad_p = torch.full_like(P.narrow(pax, 0, 1), nan)
        fwd_r, bwd_r = torch.cat([dr, pad_r], axis), torch.cat([pad_r, dr], axis)
        fwd_p, bwd_p = torch.cat([dp, pad_p], pax), torch.cat([pad_p, dp], pax)
    fin_f, fin_b = torch.isfinite(fwd_r), torch.isfinite(bwd_r)
    pick_f = fin_f & (~fin_b | (fwd_r.abs() <= bwd_r.abs()))
    return torch.where(pick_f[..., None], fwd_p, bwd_p)


def normals_from_range_t(R: torch.Tensor, directions: torch.Tensor, origins: torch.Tensor | None = None) -> torch.Tensor:
    """Eq. 4: unit normals (…,H,W,3) of range image(s) R (…,H,W) metres, facing the beam.

    The mirrored points are ``p' = o + R d`` (origins (…,H,W,3) or None = 0); the normal is the
    cross product of the row and column tangents (finite differences of neighbouring points,
    the smaller-range-jump side; columns wrap around), the same as the numpy
    :func:`holodata.geometry.unmirror.normals_from_range`. NaN where R or both neighbours along an
    axis are missing. Not differentiable through the tangent choice (use it as a fixed branch).
    """
    d = directions.to(R.dtype)
    P = R[..., None] * d
    if origins is not None:
        P = P + origins.to(R.dtype)
    t_th = _tangent(R, P, axis=-2, periodic=False)
    t_ph = _tangent(R, P, axis=-1, periodic=True)
    n = torch.linalg.cross(t_ph, t_th, dim=-1)
    n = n / torch.linalg.norm(n, dim=-1, keepdim=True)
    flip = (n * d).sum(-1, keepdim=True) > 0
    return torch.where(flip, -n, n)


def analytic_normals(R: torch.Tensor, directions: torch.Tensor, origins: torch.Tensor | None = None,
                     method: str = "planes") -> torch.Tensor:
    """The analytic branch's (mirrored) normals (N,B,H,W,3) of range images R (N,B,H,W):
    ``"difference"`` is :func:`normals_from_range_t` (eq. 4's finite differences, in torch);
    ``"planes"`` is :func:`holodata.geometry.unmirror.normals_from_range` per image (the finite-difference
    normal refined by robust window and image-plane fits: what makes a *predicted* image's normals
    fractions of a degree rather than degrees off on walls), computed in numpy, not differentiable.
    ``directions``/``origins`` (N|1,1,H,W,3)."""
    if method == "difference":
        return normals_from_range_t(R, directions, origins)
    from holodata.geometry.unmirror import normals_from_range

    Rn = R.detach().cpu().numpy()
    d = directions.detach().cpu().numpy()
    o = None if origins is None else origins.detach().cpu().numpy()
    out = np.stack([normals_from_range(Rn[i], None, None if o is None else o[min(i, len(o) - 1), 0],
                                       d[min(i, len(d) - 1), 0], method=method) for i in range(len(Rn))])
    return torch.from_numpy(out).to(device=R.device, dtype=R.dtype)


def local_frame(directions: torch.Tensor) -> torch.Tensor:
    """(…,H,W,3,3) rows [d, e_φ, e_θ] of each beam's local frame (see the module docstring)."""
    d = directions
    z = torch.zeros_like(d)
    z[..., 2] = 1.0
    e_ph = torch.linalg.cross(z, d, dim=-1)
    e_ph = e_ph / torch.linalg.norm(e_ph, dim=-1, keepdim=True).clamp_min(1e-9)
    e_th = torch.linalg.cross(d, e_ph, dim=-1)
    return torch.stack([d, e_ph, e_th], dim=-2)


def to_local(v: torch.Tensor, frame: torch.Tensor) -> torch.Tensor:
    """Components (…,3) of radar-frame vectors v (…,H,W,3) in the local frame (…,H,W,3,3)."""
    return (frame * v[..., None, :]).sum(-1)


def from_local(c: torch.Tensor, frame: torch.Tensor) -> torch.Tensor:
    """Radar-frame vectors from local components c (…,H,W,3)."""
    return (c[..., :, None] * frame).sum(-2)


def geometry_vector(n_local: torch.Tensor, clamp: float = 4.0) -> torch.Tensor:
    """Eq. 4's b (…,3) from a normal's local components: ``c / c_0`` of the normal pointing away
    from the sensor (``b_0 = 1``), the tangential components clamped to ±``clamp`` (grazing
    surfaces, |b| → ∞, would dominate an L1 loss)."""
    c0 = n_local[..., :1].abs().clamp_min(1.0 / clamp)
    s = torch.where(n_local[..., :1] > 0, 1.0, -1.0)  # flip a facing normal to point away
    bt = (s * n_local[..., 1:] / c0).clamp(-clamp, clamp)
    return torch.cat([torch.ones_like(c0), bt], -1)


def mirror_normals(normals: torch.Tensor) -> torch.Tensor:
    """Mirrored normals n'_b (…,3,H,W,3) from true normals n_b (bounce axis -4): the inverse of
    eq. 5, ``n'_b = L_1 ··· L_{b−1} n_b`` (``L_k`` reflection at n_k; the last mirror first)."""
    out = [normals[..., 0, :, :, :]]
    for b in range(1, normals.shape[-4]):
        n = normals[..., b, :, :, :]
        for k in range(b - 1, -1, -1):
            n = reflect(n, normals[..., k, :, :, :])
        out.append(n)
    return torch.stack(out, -4)


def ray_trace(R: torch.Tensor, directions: torch.Tensor, origins: torch.Tensor | None, mirrored_normals) -> dict:
    """The cascaded ray-tracing blocks (eq. 2, 3, 5), differentiable.

    R (N,B,H,W) metres (finite values; mask invalid ones yourself), directions (N|1,H,W,3),
    origins (N|1,H,W,3) or None = 0; ``mirrored_normals``: a callable ``f(b, state) -> (N,H,W,3)``
    giving bounce b's *mirrored* normal n'_b (eq. 4's normal of the range image; ``state`` holds
    the lists ``normal``, ``direction``, ``point`` of bounces < b) or a tensor (N,B,H,W,3). Bounce
    b: ``d_b = reflect(d_{b−1}, n_{b−1})`` (d_1 = beam direction), ``p_b = p_{b−1} + (R_b − R_{b−1})
    d_b`` (p_0 = o, R_0 = 0), ``n_b = L_{b−1}···L_1 n'_b`` (eq. 5, first mirror first).
    Returns dict point, normal, direction, mirrored (each (N,B,H,W,3)).
    """
    N, B = R.shape[:2]
    d = directions.to(R.dtype).expand(N, *directions.shape[-3:])
    p = torch.zeros_like(d) if origins is None else origins.to(R.dtype).expand_as(d)
    R_prev = torch.zeros_like(R[:, 0])
    st = {"normal": [], "direction": [], "point": [], "mirrored": []}
    for b in range(B):
        if b > 0:
            d = reflect(d, st["normal"][b - 1])
        p = p + (R[:, b] - R_prev)[..., None] * d
        st["direction"].append(d)
        st["point"].append(p)
        nm = mirrored_normals(b, st) if callable(mirrored_normals) else mirrored_normals[:, b]
        n = nm
        for k in range(b):
            n = reflect(n, st["normal"][k])
        st["mirrored"].append(nm)
        st["normal"].append(n)
        R_prev = R[:, b]
    return {k: torch.stack(v, 1) for k, v in st.items()}


# ----------------------------------------------------------------------------- hybrid blocks


class _Conv(nn.Module):
    """3×3 conv on beam images: circular padding along azimuth (W), zeros along elevation (H)."""

    def __init__(self, cin, cout, dilation=1):
        super().__init__()
        self.d = dilation
        self.conv = nn.Conv2d(cin, cout, 3, dilation=dilation)

    def forward(self, x):
        d = self.d
        x = F.pad(x, (d, d, 0, 0), mode="circular")
        return self.conv(F.pad(x, (0, 0, d, d)))


class _ResBlock(nn.Module):
    def __init__(self, c, dilation=1):
        super().__init__()
        self.c1, self.c2 = _Conv(c, c, dilation), _Conv(c, c, dilation)
        self.n1, self.n2 = nn.GroupNorm(4, c), nn.GroupNorm(4, c)

    def forward(self, x):
        y = F.relu(self.n1(self.c1(x)))
        return F.relu(x + self.n2(self.c2(y)))


N_BLOCK_INPUTS = 13


class HybridNormalBlock(nn.Module):
    """One hybrid estimation block (paper Fig. 12): bounce b's mirrored normal n'_b.

    Inputs per pixel (13 channels): R_b / max_range, valid_b, (R_b − R_{b−1}) / max_range, the
    analytic eq. 4 normal in the local frame (3) and its validity, the previous bounce's
    (un-mirrored) normal n_{b−1} (3) and the arriving direction d_b (3), both in the local frame.
    Residual branch: 4 residual blocks (dilations 1, 2, 4, 8); fusion branch: the branch features
    concatenated with the analytic normal, 2 residual blocks, then 4 outputs: a gate g and a
    residual r; ``n'_local = normalize(σ(g)·n_analytic + r)``, first component forced ≤ 0
    (facing the beam). The last layer starts at zero, so an untrained block is the analytic one
    (and faces the beam where eq. 4 has no answer).
    """

    def __init__(self, channels: int = 32, res_blocks: int = 4, fusion_blocks: int = 2):
        super().__init__()
        c = channels
        self.stem = _Conv(N_BLOCK_INPUTS, c)
        self.res = nn.Sequential(*[_ResBlock(c, 2 ** (i % 4)) for i in range(res_blocks)])
        self.fuse_in = _Conv(c + 4, c)
        self.fuse = nn.Sequential(*[_ResBlock(c) for _ in range(fusion_blocks)])
        self.out = nn.Conv2d(c, 4, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)
        with torch.no_grad():
            self.out.bias[0] = 3.0  # gate σ(3) ≈ 0.95: start on the analytic normal

    def forward(self, x: torch.Tensor, n_an: torch.Tensor, an_ok: torch.Tensor) -> torch.Tensor:
        """x (N,13,H,W), n_an (N,3,H,W) analytic local normal (0 where missing), an_ok (N,1,H,W)
        → (N,H,W,3) unit mirrored normal in the local frame."""
        f = self.res(F.relu(self.stem(x)))
        f = self.fuse(F.relu(self.fuse_in(torch.cat([f, n_an, an_ok], 1))))
        o = self.out(f)
        v = torch.sigmoid(o[:, :1]) * n_an + o[:, 1:]
        v = v + torch.tensor([-1e-3, 0.0, 0.0], dtype=v.dtype, device=v.device).view(1, 3, 1, 1)
        v = torch.cat([-v[:, :1].abs(), v[:, 1:]], 1)
        v = v / torch.linalg.norm(v, dim=1, keepdim=True).clamp_min(1e-9)
        return v.permute(0, 2, 3, 1)


@dataclass
class RayTracerConfig:
    """channels / res_blocks / fusion_blocks of each hybrid block (paper: 4 and 4·2 residual
    blocks); max_range (m) scales the range inputs; hybrid False = analytic branch only; normals: how
    the analytic branch estimates a normal (:func:`analytic_normals`; checkpoints without the key are
    "difference", what they were trained with)."""

    channels: int = 32
    res_blocks: int = 4
    fusion_blocks: int = 2
    max_range: float = DEFAULT_MAX_RANGE_M
    hybrid: bool = True
    normals: str = "planes"  # the analytic branch: holodata.geometry.unmirror.NORMAL_METHODS


    def to_dict(self) -> dict:
        return asdict(self)


class RayTracer(nn.Module):
    """Three hybrid normal blocks cascaded through the ray-tracing blocks (eq. 2–5).

    forward(R (N,3,H,W) NaN = none, directions (N|1,H,W,3), origins (N|1,H,W,3) or None) → dict
    point/normal/direction/mirrored (N,3,H,W,3) (NaN where R_b or an earlier bounce is missing),
    ``mirrored_local`` (N,3,H,W,3) the blocks' local-frame mirrored normals, ``valid`` (N,3,H,W).
    """

    def __init__(self, cfg: RayTracerConfig | None = None):
        super().__init__()
        self.cfg = cfg or RayTracerConfig()
        c = self.cfg
        self.blocks = nn.ModuleList([HybridNormalBlock(c.channels, c.res_blocks, c.fusion_blocks) for _ in range(3)])

    def forward(self, R: torch.Tensor, directions: torch.Tensor, origins: torch.Tensor | None = None) -> dict:
        N, B, H, W = R.shape
        dt = R.dtype
        dirs = directions.to(dt)
        if dirs.dim() == 3:
            dirs = dirs[None]
        org = None if origins is None else (origins.to(dt)[None] if origins.dim() == 3 else origins.to(dt))
        valid = torch.isfinite(R)
        chain = torch.cumprod(valid.to(dt), 1) > 0  # R_1..R_b all present
        with torch.no_grad():  # float64 like the numpy version (float32 ties pick other tangents)
            n_an_rad = analytic_normals(R.double(), dirs[:, None].double(),
                                        None if org is None else org[:, None].double(), self.cfg.normals).to(dt)
        frame = local_frame(dirs)  # (N|1,H,W,3,3)
        n_an = torch.nan_to_num(to_local(n_an_rad, frame[:, None]), nan=0.0)
        an_ok = torch.isfinite(n_an_rad).all(-1) & chain
        n_an = n_an * an_ok[..., None]
        Rf = torch.nan_to_num(R, nan=0.0) * chain
        mr = float(self.cfg.max_range)
        local_out = []

        def mirrored(b, st):
            if not self.cfg.hybrid:
                nl = torch.where(an_ok[:, b, ..., None], n_an[:, b], torch.tensor([-1.0, 0, 0], dtype=dt, device=R.device))
            else:
                prev_n = to_local(st["normal"][b - 1], frame) if b > 0 else torch.zeros_like(n_an[:, 0])
                d_loc = to_local(st["direction"][b], frame)
                seg = Rf[:, b] - (Rf[:, b - 1] if b > 0 else 0.0)
                x = torch.cat([(Rf[:, b] / mr)[:, None], chain[:, b, None].to(dt), (seg / mr)[:, None],
                               n_an[:, b].permute(0, 3, 1, 2), an_ok[:, b, None].to(dt),
                               prev_n.permute(0, 3, 1, 2), d_loc.permute(0, 3, 1, 2)], 1)
                nl = self.blocks[b](x, n_an[:, b].permute(0, 3, 1, 2), an_ok[:, b, None].to(dt))
            local_out.append(nl)
            return from_local(nl, frame)

        out = ray_trace(Rf, dirs, org, mirrored)
        out["mirrored_local"] = torch.stack(local_out, 1)
        out["valid"] = chain
        nan = torch.tensor(float("nan"), dtype=dt, device=R.device)
        for k in ("point", "normal", "direction", "mirrored"):
            out[k] = torch.where(chain[..., None], out[k], nan)
        return out


def ray_trace_loss(out: dict, gt_point: torch.Tensor, gt_normal: torch.Tensor, directions: torch.Tensor,
                   mask: torch.Tensor | None = None, w_sn: float = 1.0, w_point: float = 1.0,
                   w_normal: float = 0.5) -> tuple[torch.Tensor, dict]:
    """Eq. 6: ``λ_sn Σ_b |b̂_b − b_b|_1 + λ_point Σ_b |p̂_b − p_b|_1`` (means over valid pixels),
    plus ``w_normal`` × L1 of the unit mirrored normals (a steadier signal at grazing angles).

    out: :class:`RayTracer` output; gt_point / gt_normal (N,3,H,W,3) radar frame (true normals;
    NaN = none); directions (N|1,H,W,3); mask (N,3,H,W) extra pixels to use (e.g. where the
    input range is close to the GT one)."""
    dirs = directions if directions.dim() == 4 else directions[None]
    frame = local_frame(dirs.to(gt_normal.dtype))[:, None]
    gt_mir = mirror_normals(gt_normal)
    gl = to_local(gt_mir, frame)
    pl = out["mirrored_local"]
    ok_n = torch.isfinite(gl).all(-1) & out["valid"]
    ok_p = torch.isfinite(gt_point).all(-1) & out["valid"]
    if mask is not None:
        ok_n, ok_p = ok_n & mask, ok_p & mask
    zero = pl.sum() * 0.0
    parts = {}
    if ok_n.any():
        gb, pb = geometry_vector(gl[ok_n]), geometry_vector(pl[ok_n])
        parts["b"] = (pb - gb).abs().sum(-1).mean()
        gn = -gl[ok_n] * torch.where(gl[ok_n][:, :1] > 0, 1.0, -1.0)  # facing the beam
        parts["normal"] = (pl[ok_n] - gn).abs().sum(-1).mean()
    else:
        parts["b"] = parts["normal"] = zero
    if ok_p.any():
        parts["point"] = (out["point"][ok_p] - gt_point[ok_p]).abs().sum(-1).mean()
    else:
        parts["point"] = zero
    total = w_sn * parts["b"] + w_point * parts["point"] + w_normal * parts["normal"]
    return total, {k: float(v.detach()) for k, v in parts.items()}


# ----------------------------------------------------------------------------- sparse voxels

_KEY_BITS = 20
_KEY_OFF = 1 << (_KEY_BITS - 1)


def voxel_keys(coords: torch.Tensor) -> torch.Tensor:
    """int64 keys of integer voxel coordinates (M,4) [batch, x, y, z] (|x|,|y|,|z| < 2^19)."""
    c = coords.long()
    k = c[:, 0]
    for i in (1, 2, 3):
        k = (k << _KEY_BITS) | (c[:, i] + _KEY_OFF)
    return k


def lookup(sorted_keys: torch.Tensor, order: torch.Tensor, query: torch.Tensor, missing: int) -> torch.Tensor:
    """Index (into the unsorted key array) of each query key, ``missing`` where absent."""
    pos = torch.searchsorted(sorted_keys, query).clamp(max=max(len(sorted_keys) - 1, 0))
    hit = sorted_keys[pos] == query if len(sorted_keys) else torch.zeros_like(query, dtype=torch.bool)
    return torch.where(hit, order[pos], torch.full_like(query, missing))


_OFFSETS = torch.stack(torch.meshgrid(*[torch.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3)


def unique_coords(coords: torch.Tensor):
    """Unique voxel coordinates (M,4) of (P,4), the inverse index (P,) and counts (M,) (via 1-D
    keys: torch.unique(dim=0) is ~40× slower on CPU)."""
    keys = voxel_keys(coords)
    uk, inv, counts = torch.unique(keys, return_inverse=True, return_counts=True)
    first = torch.zeros(len(uk), dtype=torch.long, device=coords.device).scatter_(
        0, inv, torch.arange(len(keys), device=coords.device))
    return coords[first], inv, counts


def neighbour_table(coords: torch.Tensor) -> torch.Tensor:
    """(M,27) index of each voxel's 3×3×3 neighbours among ``coords`` (M,4); M where absent."""
    keys = voxel_keys(coords)
    sk, order = torch.sort(keys)
    off = torch.cat([torch.zeros(27, 1, dtype=torch.long), _OFFSETS], 1).to(coords.device)
    q = voxel_keys((coords[:, None, :] + off[None]).reshape(-1, 4)).view(-1, 27)
    return lookup(sk, order, q.reshape(-1), len(coords)).view(-1, 27)


def scatter_mean(x: torch.Tensor, index: torch.Tensor, n: int) -> torch.Tensor:
    """Mean of rows of x (P,C) per group ``index`` (P,) in [0, n) → (n,C) (0 for empty groups)."""
    s = torch.zeros(n, x.shape[1], dtype=x.dtype, device=x.device).index_add_(0, index, x)
    c = torch.zeros(n, dtype=x.dtype, device=x.device).index_add_(0, index, torch.ones_like(index, dtype=x.dtype))
    return s / c.clamp_min(1)[:, None]


class SparseConv3(nn.Module):
    """Submanifold 3×3×3 convolution on occupied voxels: gather the 27 neighbours' features
    (zeros where unoccupied) and multiply by a (27·C_in, C_out) weight. Plain torch (gather +
    matmul), so backward works on CPU and CUDA."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.weight = nn.Parameter(torch.randn(27 * cin, cout) / math.sqrt(27 * cin))
        self.bias = nn.Parameter(torch.zeros(cout))

    def forward(self, x: torch.Tensor, nbr: torch.Tensor) -> torch.Tensor:
        xp = torch.cat([x, x.new_zeros(1, x.shape[1])], 0)
        return xp[nbr].reshape(len(x), -1) @ self.weight + self.bias


class _SparseRes(nn.Module):
    def __init__(self, c):
        super().__init__()
        self.c1, self.c2 = SparseConv3(c, c), SparseConv3(c, c)
        self.n1, self.n2 = nn.LayerNorm(c), nn.LayerNorm(c)

    def forward(self, x, nbr):
        y = F.relu(self.n1(self.c1(x, nbr)))
        return F.relu(x + self.n2(self.c2(y, nbr)))


N_POINT_FEATURES = 13


@dataclass
class RefinerConfig:
    """voxel (m, paper 0.078 × 0.078 × 0.11 at 256×256×32 over 20×20×3.5 m); channels per UNet
    level (len = levels; each coarser level halves the resolution); blocks per level; max_offset
    (voxels) of the regressed offset; max_range (m) scales xyz."""

    voxel: float = 0.1
    channels: tuple = (16, 32, 48, 64)
    blocks: int = 1
    max_offset: float = 0.75
    max_range: float = DEFAULT_MAX_RANGE_M

    def to_dict(self) -> dict:
        d = asdict(self)
        d["channels"] = list(self.channels)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> RefinerConfig:
        return cls(**{**d, "channels": tuple(d["channels"])})


@dataclass
class Voxels:
    """A batch of voxelised points. coords (M,4) [batch, x, y, z] int64 voxel indices; ``point_voxel``
    (P,) the voxel of every input point; features (P, 12) per-point features."""

    coords: torch.Tensor
    point_voxel: torch.Tensor
    features: torch.Tensor
    voxel: float


def voxelize(points: torch.Tensor, batch: torch.Tensor, bounce: torch.Tensor, human: torch.Tensor,
             voxel: float, max_range: float, los: torch.Tensor | None = None) -> Voxels:
    """Voxelise points (P,3) m of frames ``batch`` (P,) with bounce index (P,) in 0..2 and stage-one
    human probability (P,). Per-point features (the paper's (x, y, z, Δx, Δy, Δz, i, n) plus the
    human probability and the point's LOS flag): xyz / max_range (3), offset to the voxel centre /
    voxel (3), bounce one-hot (3), log(1 + points in the voxel) (1), human probability (1), LOS flag
    (1; visible in the first-bounce image, 0 when not given), 1 (a bias input)."""
    ijk = torch.floor(points / voxel).long()
    coords_p = torch.cat([batch.long()[:, None], ijk], 1)
    coords, inv, counts = unique_coords(coords_p)
    centre = (ijk.to(points.dtype) + 0.5) * voxel
    feat = torch.cat([points / max_range, (points - centre) / voxel, F.one_hot(bounce.long(), 3).to(points.dtype),
                      torch.log1p(counts[inv].to(points.dtype))[:, None], human[:, None].to(points.dtype),
                      (torch.zeros_like(points[:, 0]) if los is None else los.to(points.dtype))[:, None],
                      torch.ones_like(points[:, :1])], 1)
    return Voxels(coords, inv, feat, voxel)


def voxel_point_mean(vox: Voxels, values: torch.Tensor) -> torch.Tensor:
    """(M,) mean of a per-point quantity (P,) over the input points of each voxel (e.g. the LOS
    flag or the stage-one human probability: what the refined voxel inherits from its points)."""
    return scatter_mean(values.to(vox.features.dtype)[:, None], vox.point_voxel, len(vox.coords))[:, 0]


class VoxelEncoder(nn.Module):
    """Per-point MLP, then the mean over the points of each voxel (paper: "averaged to obtain the
    voxel feature when multiple points fall into the same voxel")."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(cin, cout), nn.ReLU(), nn.Linear(cout, cout))

    def forward(self, feats: torch.Tensor, point_voxel: torch.Tensor, n_voxels: int) -> torch.Tensor:
        return scatter_mean(self.mlp(feats), point_voxel, n_voxels)


class VoxelRefiner(nn.Module):
    """Sparse 3-D UNet over the occupied voxels (submanifold convolutions; each coarser level is
    the set of parent voxels, features mean-pooled down and gathered back up with a skip
    concatenation). Heads: class logits (empty, human, structure) and offset (voxels, ±max_offset).

    forward(Voxels) → dict cls_logit (M,3), offset (M,3) in metres, centre (M,3) metres, voxel (m)."""

    def __init__(self, cfg: RefinerConfig | None = None):
        super().__init__()
        self.cfg = cfg or RefinerConfig()
        ch = list(self.cfg.channels)
        self.encoder = VoxelEncoder(N_POINT_FEATURES, ch[0])
        self.down = nn.ModuleList()
        self.enc = nn.ModuleList()
        for i, c in enumerate(ch):
            self.down.append(nn.Identity() if i == 0 else nn.Linear(ch[i - 1], c))
            self.enc.append(nn.ModuleList([_SparseRes(c) for _ in range(self.cfg.blocks)]))
        self.up = nn.ModuleList([nn.Linear(ch[i] + ch[i + 1], ch[i]) for i in range(len(ch) - 1)])
        self.dec = nn.ModuleList([nn.ModuleList([_SparseRes(ch[i]) for _ in range(self.cfg.blocks)])
                                  for i in range(len(ch) - 1)])
        self.cls = nn.Linear(ch[0], 3)
        self.reg = nn.Linear(ch[0], 3)
        nn.init.zeros_(self.reg.weight)
        nn.init.zeros_(self.reg.bias)

    def forward(self, vox: Voxels) -> dict:
        coords = vox.coords
        x = self.encoder(vox.features, vox.point_voxel, len(coords))
        levels = []
        for i in range(len(self.enc)):
            if i > 0:
                parent = torch.cat([coords[:, :1], torch.div(coords[:, 1:], 2, rounding_mode="floor")], 1)
                coords, inv, _ = unique_coords(parent)
                x = self.down[i](scatter_mean(x, inv, len(coords)))
                levels[-1]["parent"] = inv
            nbr = neighbour_table(coords)
            for blk in self.enc[i]:
                x = blk(x, nbr)
            levels.append({"x": x, "nbr": nbr})
        for i in range(len(self.enc) - 2, -1, -1):
            lv = levels[i]
            x = F.relu(self.up[i](torch.cat([lv["x"], x[lv["parent"]]], 1)))
            for blk in self.dec[i]:
                x = blk(x, lv["nbr"])
        v = vox.voxel
        centre = (vox.coords[:, 1:].to(x.dtype) + 0.5) * v
        return {"cls_logit": self.cls(x), "offset": torch.tanh(self.reg(x)) * self.cfg.max_offset * v,
                "centre": centre, "voxel": v}


CLASS_EMPTY, CLASS_HUMAN, CLASS_STRUCTURE = 0, 1, 2


def refine_loss(out: dict, cls_target: torch.Tensor, reg_target: torch.Tensor, edt: torch.Tensor,
                w_cls: float = 1.0, w_reg: float = 1.0, w_dist: float = 0.2,
                class_weight: torch.Tensor | None = None) -> tuple[torch.Tensor, dict]:
    """Eq. 7: ``λ_cls CE(V̂_cls, V_cls) + λ_reg |V̂_reg − V_reg|_1 + λ_dist |V̂_cls ∗ EDT(V_cls)|_1``.

    cls_target (M,) long (0 empty, 1 human, 2 structure) per occupied input voxel; reg_target (M,3)
    metres (offset of the GT points' mean from the voxel centre; used where the class is not
    empty, divided by the voxel size); edt (M,) distance (voxels) from each voxel to the nearest GT
    occupied voxel. The distance term weights the predicted non-empty probability by that distance
    (the volume V̂_cls read as P(non-empty))."""
    logit = out["cls_logit"]
    parts = {"cls": F.cross_entropy(logit, cls_target, weight=class_weight)}
    occ = cls_target != CLASS_EMPTY
    v = float(out.get("voxel", 1.0))
    if occ.any():
        parts["reg"] = ((out["offset"][occ] - reg_target[occ]).abs().sum(-1) / v).mean()
    else:
        parts["reg"] = logit.sum() * 0.0
    p_occ = 1.0 - torch.softmax(logit, -1)[:, CLASS_EMPTY]
    parts["dist"] = (p_occ * edt).mean()
    total = w_cls * parts["cls"] + w_reg * parts["reg"] + w_dist * parts["dist"]
    return total, {k: float(v.detach()) for k, v in parts.items()}
