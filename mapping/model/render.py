"""Rays, samples along them, and occupancy rendering (paper eq. 6-7), for one instance or composited.

Conventions: ray directions have unit z in the camera frame (vMAP's "z" depth type), so the ray
parameter t of a point IS its depth in the camera, directly comparable with depth images; origins and
directions are world coordinates; a camera pose is camera-to-world with OpenCV axes (see
``mapping.data.frame``). Depths along a ray are sorted ascending wherever they are rendered.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, Sequence

import torch
from torch import Tensor

from mapping.config_fields import bounded
from mapping.data.frame import Intrinsics

FREE_PROBABILITY_FLOOR = 1e-10
"""1 - o is floored here before its log (o rounds to exactly 1 in float32; vMAP adds the same 1e-10)."""


# ---- rays -------------------------------------------------------------------------------------------
@dataclass
class RayBundle:
    """Rays of any batch shape: ``origins`` and ``directions`` (*batch, 3), world coordinates."""

    origins: Tensor
    directions: Tensor

    def __post_init__(self) -> None:
        if self.origins.shape[-1] != 3 or self.origins.shape != self.directions.shape:
            raise ValueError(f"origins {tuple(self.origins.shape)} and directions {tuple(self.directions.shape)} "
                             "must both be (*batch, 3)")

    @property
    def shape(self) -> torch.Size:
        return self.origins.shape[:-1]

    def __len__(self) -> int:
        return self.origins.shape[0]

    def __getitem__(self, index) -> "RayBundle":
        return RayBundle(self.origins[index], self.directions[index])

    def flatten(self) -> "RayBundle":
        """(R,) rays."""
        return RayBundle(self.origins.reshape(-1, 3), self.directions.reshape(-1, 3))

    def at(self, depths: Tensor) -> Tensor:
        """(*batch, S, 3) points at (*batch, S) ray parameters (= camera depths)."""
        return self.origins[..., None, :] + self.directions[..., None, :] * depths[..., None]


def camera_rays(c2w: Tensor, intrinsics: Intrinsics, u: Tensor, v: Tensor) -> RayBundle:
    """Rays through pixel coordinates (u, v) (pixel centres at integers, OpenCV).

    Args:
        c2w: (4, 4) or (*batch, 4, 4) camera-to-world poses.
        intrinsics: the pinhole camera.
        u, v: (*batch,) pixel column and row.
    """
    x, y = (u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy
    cam = torch.stack([x, y, torch.ones_like(u)], -1)
    rotation, origin = c2w[..., :3, :3], c2w[..., :3, 3]
    directions = (rotation @ cam.unsqueeze(-1)).squeeze(-1)
    return RayBundle(origin.expand_as(directions).contiguous(), directions)


def image_rays(c2w: Tensor, intrinsics: Intrinsics, stride: int = 1) -> RayBundle:
    """(H', W') rays of every ``stride``-th pixel of an image seen from ``c2w`` (4, 4)."""
    c2w = torch.as_tensor(c2w, dtype=torch.float32)
    v, u = torch.meshgrid(torch.arange(0, intrinsics.height, stride, dtype=torch.float32, device=c2w.device),
                          torch.arange(0, intrinsics.width, stride, dtype=torch.float32, device=c2w.device),
                          indexing="ij")
    return camera_rays(c2w, intrinsics, u, v)


def ray_aabb(origins: Tensor, directions: Tensor, bound_min: Tensor, bound_max: Tensor) -> tuple[Tensor, Tensor]:
    """Slab test: ray parameters where each ray enters and leaves each box (broadcasting).

    Args:
        origins, directions: (..., 3).
        bound_min, bound_max: (..., 3) box corners, broadcastable against the rays.

    Returns:
        t_near, t_far (...): the ray hits the box in front of ``near`` when t_far > max(t_near, near).
    """
    safe = torch.where(directions.abs() < 1e-12, torch.full_like(directions, 1e-12).copysign(directions), directions)
    inv = 1.0 / safe
    t0, t1 = (bound_min - origins) * inv, (bound_max - origins) * inv
    return torch.minimum(t0, t1).amax(-1), torch.maximum(t0, t1).amin(-1)


# ---- sampling (vMAP's training samples) -------------------------------------------------------------
@dataclass(frozen=True)
class SamplerConfig:
    """vMAP's per-ray samples for training one instance."""

    n_stratified: int = field(default=1, metadata=bounded(0, 1024))
    """Samples between the near bound and d - surface_eps (vMAP: 1 for objects, 5 for background)."""
    n_surface: int = field(default=9, metadata=bounded(0, 1024))
    """Samples around the observed depth d (vMAP: 9)."""
    surface_eps_m: float = field(default=0.1, metadata=bounded(0, 10, low_open=True))
    """Half-width of the surface band; own rays draw N(d, eps/3) clipped to d +- eps (vMAP: 0.1)."""
    other_eps_m: float = field(default=0.05, metadata=bounded(0, 10))
    """Rays on other surfaces sample [d - eps, d + other_eps]: free space up to just behind them (vMAP: 0.05)."""
    near_m: float = field(default=0.0, metadata=bounded(0, 1000))
    """Near bound (vMAP: depth range [0, 8])."""
    far_m: float = field(default=8.0, metadata=bounded(0, 1000, low_open=True))
    """Far bound, used by rays without depth."""


@dataclass
class RaySamples:
    """Samples along rays.

    Attributes:
        depths: (*batch, S) ray parameters (camera depths), ascending.
        positions: (*batch, S, 3) world points.
        occluded: (*batch,) bool, the observed surface lies before ``near``: the samples lie behind it,
            where nothing was seen, so these rays must not be supervised (pass ``~occluded`` as
            ``valid`` to ``data_loss``).
    """

    depths: Tensor
    positions: Tensor
    occluded: Tensor


def stratified(lo: Tensor, hi: Tensor, n: int, generator: torch.Generator | None = None) -> Tensor:
    """(*batch, n): one uniform sample in each of n equal bins of [lo, hi] ((*batch,) each), ascending."""
    u = torch.rand(*lo.shape, n, generator=generator, device=lo.device, dtype=lo.dtype)
    edges = torch.arange(n, device=lo.device, dtype=lo.dtype)
    return lo[..., None] + (hi - lo)[..., None] * (edges + u) / n


def sample_along_rays(rays: RayBundle, depth: Tensor, own: Tensor | None = None,
                      config: SamplerConfig = SamplerConfig(), near: Tensor | float | None = None,
                      far: Tensor | float | None = None, generator: torch.Generator | None = None) -> RaySamples:
    """vMAP's training samples along each ray (n_stratified + n_surface per ray, sorted).

    - depth d in (near, far], pixel of this instance (``own``): n_stratified in [near, d - eps],
      n_surface from N(d, eps/3) clipped to d +- eps;
    - depth d in (near, far], pixel of another surface: n_stratified in [near, d - eps], n_surface
      stratified in [d - eps, d + other_eps] (the instance must be empty up to just behind it);
    - no depth (0 or non-finite), or d beyond far (the whole [near, far] is free): all samples
      stratified in [near, far];
    - d before near: the same samples, flagged ``occluded`` (not to be supervised).

    Args:
        rays: (*batch) rays.
        depth: (*batch,) observed depth, metres (0 = none).
        own: (*batch,) bool, the pixel belongs to the instance (None: all do).
        config: counts and bands.
        near, far: scalars or (*batch,) bounds overriding the config, e.g. the instance box's entry and
            exit from ``ray_aabb``, so that training samples the same region the composite renders.
        generator: random source.
    """
    shape, dev = depth.shape, depth.device
    near_t = torch.as_tensor(config.near_m if near is None else near, dtype=depth.dtype, device=dev).expand(shape)
    far_t = torch.as_tensor(config.far_m if far is None else far, dtype=depth.dtype, device=dev).expand(shape)
    own = torch.ones(shape, dtype=torch.bool, device=dev) if own is None else own.to(torch.bool)
    eps = config.surface_eps_m
    seen = torch.isfinite(depth) & (depth > 0)
    valid = seen & (depth > near_t) & (depth <= far_t)
    d = torch.where(valid, depth, far_t)

    front = stratified(near_t, torch.maximum(d - eps, near_t), config.n_stratified, generator)
    noise = torch.randn(*shape, config.n_surface, generator=generator, device=dev, dtype=depth.dtype)
    around_own = d[..., None] + (noise * (eps / 3.0)).clamp(-eps, eps).sort(dim=-1).values
    around_other = stratified(d - eps, d + config.other_eps_m, config.n_surface, generator)
    around = torch.where(own[..., None], around_own, around_other)
    no_depth = stratified(near_t, torch.maximum(far_t, near_t), config.n_stratified + config.n_surface, generator)
    depths = torch.where(valid[..., None], torch.cat([front, around], dim=-1), no_depth)
    # The surface band may start before ``near`` (the box's entry, padded 5 cm, while the band is
    # +-10 cm): sort so that eq. 6 composites the samples in depth order.
    depths = depths.sort(dim=-1).values
    return RaySamples(depths, rays.at(depths), seen & (depth <= near_t))


# ---- rendering (eq. 6-7) ----------------------------------------------------------------------------
@dataclass
class RenderedRays:
    """Per-ray renderings of eq. 7 and the termination weights T_p of eq. 6.

    Attributes:
        occupancy: (*batch,) O_hat = sum_p T_p.
        depth: (*batch,) D_hat = sum_p T_p d_p.
        colour: (*batch, 3) C_hat = sum_p T_p c_p, or None.
        weights: (*batch, S) T_p.
        depth_variance: (*batch,) sum_p T_p (d_p - D_hat)^2 (vMAP's depth uncertainty).
    """

    occupancy: Tensor
    depth: Tensor
    colour: Tensor | None
    weights: Tensor
    depth_variance: Tensor


def termination_probabilities(occupancy: Tensor) -> Tensor:
    """Eq. 6: T_p = o_p prod_{q<p} (1 - o_q), for (*batch, S) occupancies of depth-sorted samples.

    The product is an exclusive cumulative sum of log(1 - o) (floored at 1e-10) exponentiated: no
    underflowing product whose backward would divide by zero.
    """
    log_free = torch.log((1.0 - occupancy).clamp_min(FREE_PROBABILITY_FLOOR))
    log_transmittance = torch.cumsum(log_free, dim=-1)
    log_transmittance = torch.cat([torch.zeros_like(log_transmittance[..., :1]), log_transmittance[..., :-1]], dim=-1)
    return occupancy * torch.exp(log_transmittance)


def render_occupancy(occupancy: Tensor, colour: Tensor | None, depths: Tensor) -> RenderedRays:
    """Eq. 6-7 along rays of depth-sorted samples.

    Args:
        occupancy: (*batch, S) o_p in [0, 1].
        colour: (*batch, S, 3) c_p, or None.
        depths: (*batch, S) d_p, ascending along the last axis.
    """
    weights = termination_probabilities(occupancy)
    depth = (weights * depths).sum(-1)
    variance = (weights * (depths - depth[..., None]).square()).sum(-1)
    rendered_colour = None if colour is None else (weights[..., None] * colour).sum(-2)
    return RenderedRays(weights.sum(-1), depth, rendered_colour, weights, variance)


# ---- multi-instance compositing ---------------------------------------------------------------------
class InstanceField(Protocol):
    """What compositing needs of a bank (``InstanceFieldBank`` has it; so can a test's analytic field)."""

    bound_min: Tensor  # (N, 3)
    bound_max: Tensor  # (N, 3)

    @property
    def num_instances(self) -> int: ...

    def query(self, points: Tensor, rows: Tensor, with_colour: bool = True, block_size: int = 4096): ...


@dataclass(frozen=True)
class CompositeConfig:
    """Sampling of every instance box a ray crosses, for rendering whole views."""

    samples_per_box: int = 48
    """Evenly spaced samples in each box a ray crosses (depth resolution: box chord / this)."""
    near_m: float = 0.05
    """Nothing nearer the camera is rendered."""
    far_m: float = 20.0
    """Nothing farther is rendered."""
    rays_per_chunk: int = 4096
    """Rays composited at once by ``render_image`` (memory bound)."""
    block_size: int = 4096
    """Points per batch entry of the packed field query (see ``InstanceFieldBank.query``)."""
    min_occupancy: float = 0.5
    """The instance image is -1 where a ray renders less occupancy than this."""


@dataclass
class CompositeRender:
    """Composited rendering: depth (*batch,), occupancy (*batch,), colour (*batch, 3) or None, and
    instance (*batch,) long: the label of the instance with the largest summed termination weight
    (-1 where the ray renders occupancy below ``min_occupancy``)."""

    depth: Tensor
    occupancy: Tensor
    colour: Tensor | None
    instance: Tensor
    weights: Tensor | None = None
    """(n_rays, M) termination weights T_p of the flattened rays' depth-sorted samples (differentiable)."""
    sample_depths: Tensor | None = None
    """(n_rays, M) the samples' depths (padding slots lie beyond ``far_m`` with weight 0)."""


def composite_instances(fields: Sequence[InstanceField], rays: RayBundle, config: CompositeConfig = CompositeConfig(),
                        with_colour: bool = True, labels: Sequence[Tensor] | None = None) -> CompositeRender:
    """Render rays through all instances of all banks, composited by depth (vMAP; paper Sec. IV-C).

    For each (instance, ray) whose box the ray crosses (slab test), ``samples_per_box`` evenly spaced
    samples inside the box; every bank evaluates all its samples in one packed batched query; each
    ray's samples from all instances are then sorted by depth and rendered with eq. 6-7.
    Differentiable (the render-consistency loss can use it); ``render_image`` chunks it without grad.

    Args:
        fields: the banks (e.g. objects W=32 and structure W=128).
        rays: (*batch) rays.
        labels: optional (N_b,) long per bank giving each row's label for the instance output;
            default: rows numbered across banks in order (bank 0's rows first).
    """
    flat = rays.flatten()
    origins, directions = flat.origins, flat.directions
    n_rays, n_samples, dev = origins.shape[0], config.samples_per_box, origins.device
    mid = (torch.arange(n_samples, device=dev, dtype=origins.dtype) + 0.5) / n_samples
    pair_ray, pair_label, pair_depths, pair_occ, pair_col = [], [], [], [], []
    offset = 0
    for b, field in enumerate(fields):
        n = field.num_instances
        if n == 0:
            continue
        t_near, t_far = ray_aabb(origins[None], directions[None], field.bound_min[:, None], field.bound_max[:, None])
        t_near, t_far = t_near.clamp_min(config.near_m), t_far.clamp_max(config.far_m)  # (N, R)
        inst, ray = torch.nonzero(t_far > t_near, as_tuple=True)
        if len(inst):
            depths = t_near[inst, ray, None] + (t_far - t_near)[inst, ray, None] * mid  # (Q, S)
            points = origins[ray, None] + directions[ray, None] * depths[..., None]
            out = field.query(points.reshape(-1, 3), inst.repeat_interleave(n_samples), with_colour=with_colour,
                              block_size=config.block_size)
            pair_ray.append(ray)
            pair_label.append(labels[b].to(dev)[inst] if labels is not None else inst + offset)
            pair_depths.append(depths)
            pair_occ.append(out.occupancy.reshape(-1, n_samples))
            if with_colour:
                pair_col.append(out.colour.reshape(-1, n_samples, 3))
        offset += n
    if not pair_ray:
        zeros = origins.new_zeros(n_rays)
        return CompositeRender(zeros.reshape(rays.shape), zeros.reshape(rays.shape),
                               origins.new_zeros(*rays.shape, 3) if with_colour else None,
                               torch.full(rays.shape, -1, dtype=torch.long, device=dev))

    # Pack each ray's (instance, ray) pairs into (R, K, S) slots, K = most boxes crossed by one ray.
    ray_of = torch.cat(pair_ray)
    order = torch.argsort(ray_of, stable=True)
    ray_sorted = ray_of[order]
    counts = torch.bincount(ray_sorted, minlength=n_rays)
    k_max = int(counts.max())
    slot = torch.arange(len(order), device=dev) - (torch.cumsum(counts, 0) - counts)[ray_sorted]
    index = (ray_sorted, slot)
    pad_depth = config.far_m + 1.0  # empty slots: occupancy 0 behind everything
    depths = origins.new_full((n_rays, k_max, n_samples), pad_depth).index_put(index, torch.cat(pair_depths)[order])
    occ = origins.new_zeros(n_rays, k_max, n_samples).index_put(index, torch.cat(pair_occ)[order])
    label = torch.full((n_rays, k_max), -1, dtype=torch.long, device=dev).index_put(index, torch.cat(pair_label)[order])

    # Sort all samples of a ray by depth and render (eq. 6-7).
    depths, by_depth = depths.reshape(n_rays, -1).sort(dim=-1)
    occ = occ.reshape(n_rays, -1).gather(1, by_depth)
    colour = None
    if with_colour:
        col = origins.new_zeros(n_rays, k_max, n_samples, 3).index_put(index, torch.cat(pair_col)[order])
        colour = col.reshape(n_rays, -1, 3).gather(1, by_depth[..., None].expand(-1, -1, 3))
    rendered = render_occupancy(occ, colour, depths)

    # Instance of each ray: the pair holding most of the termination weight.
    weight_per_pair = torch.zeros_like(rendered.weights).scatter(1, by_depth, rendered.weights.detach())
    best = weight_per_pair.reshape(n_rays, k_max, n_samples).sum(-1).argmax(-1)
    instance = label.gather(1, best[:, None])[:, 0]
    instance = torch.where(rendered.occupancy.detach() >= config.min_occupancy, instance, torch.full_like(instance, -1))
    return CompositeRender(rendered.depth.reshape(rays.shape), rendered.occupancy.reshape(rays.shape),
                           None if rendered.colour is None else rendered.colour.reshape(*rays.shape, 3),
                           instance.reshape(rays.shape), rendered.weights, depths)


@torch.no_grad()
def render_image(fields: Sequence[InstanceField], c2w: Tensor, intrinsics: Intrinsics,
                 config: CompositeConfig = CompositeConfig(), stride: int = 1, with_colour: bool = True,
                 labels: Sequence[Tensor] | None = None) -> CompositeRender:
    """Depth, colour, occupancy and instance images (H', W') seen from ``c2w`` (4, 4), every
    ``stride``-th pixel, composited over all instances in chunks of ``config.rays_per_chunk`` rays."""
    device = next((f.bound_min.device for f in fields), torch.device("cpu"))
    rays = image_rays(torch.as_tensor(c2w, dtype=torch.float32, device=device), intrinsics, stride)
    flat = rays.flatten()
    parts = [composite_instances(fields, flat[i : i + config.rays_per_chunk], config, with_colour, labels)
             for i in range(0, len(flat), config.rays_per_chunk)]
    shape = rays.shape
    return CompositeRender(
        depth=torch.cat([p.depth for p in parts]).reshape(shape),
        occupancy=torch.cat([p.occupancy for p in parts]).reshape(shape),
        colour=torch.cat([p.colour for p in parts]).reshape(*shape, 3) if with_colour else None,
        instance=torch.cat([p.instance for p in parts]).reshape(shape),
    )
