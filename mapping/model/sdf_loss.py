"""MACIM's training signal for its scene SDF (iSDF's losses): samples along depth rays, batch distance
bounds, the truncated SDF loss and the eikonal term.

Read from ``BIT-DYN/MACIM`` (``mocim/modules/sample.py``, ``loss.py``, ``train/configs/replicaCAD.json``):

- per step 200 rays of valid depth d; along each, d itself, 4 samples from N(d, 0.1 m) and 22 stratified
  samples, all in [0.07 m, d + 0.1 m];
- the bound of a sample: its distance to the nearest surface point of any ray of the step ("pc" bounds),
  negative behind its own ray's surface;
- within the truncation band (|bound| <= 0.296 m) the L1 of sdf - bound, weighted 3.38; beyond it (free
  space) max(relu(sdf - bound), exp(-5 sdf) - 1): never above the bound and never negative; every
  sample's term capped at 2 (their multi-robot setting);
- eikonal: | |grad sdf| - 1 | where the bound is at least 0.1 m, weighted 0.0268;
- the mean over all samples.

Not taken (``docs/baselines.md``): their normal-direction term (weight 0.00018), MACIM's replay of a voxel
grid of fused bounds and its prior for voxels no robot observed; the keyframe buffer stands in for the replay.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from mapping.config_fields import bounded


@dataclass(frozen=True)
class SdfConfig:
    """MACIM's published map: network, samples, losses, optimiser and iteration budget."""

    width: int = field(default=256, metadata=bounded(1, 4096))
    """Hidden width (``hidden_feature_size``)."""
    scale_output: float = field(default=0.14, metadata=bounded(0, 1000, low_open=True))
    """The network's output times this is the signed distance in metres."""
    encoding_per_m: float = field(default=0.05937489, metadata=bounded(0, 1000, low_open=True))
    """Coordinates (metres from the scene centre) are multiplied by this before the encoding."""
    occupancy_sharpness: float = field(default=50.0, metadata=bounded(0, 1e6, low_open=True))
    """Ours, not theirs: the map's occupancy is sigmoid(-sharpness * sdf), so meshing at 0.5 is the zero
    level set and the occupancy renderers (pictures, the depth check, the reward's probes) read the SDF."""
    rays: int = field(default=200, metadata=bounded(1, 65_536))
    """Rays per step (``n_rays``)."""
    n_stratified: int = field(default=22, metadata=bounded(0, 1024))
    """Stratified samples per ray between the near bound and the surface (``n_strat_samples``)."""
    n_surface: int = field(default=5, metadata=bounded(1, 1024))
    """The surface sample itself and four around it."""
    min_depth_m: float = field(default=0.07, metadata=bounded(0, 1000))
    """Near bound of the stratified samples (``min_depth``)."""
    behind_surface_m: float = field(default=0.1, metadata=bounded(0, 1000))
    """How far behind the measured surface the stratified samples reach (``dist_behind_surf``)."""
    surface_std_m: float = field(default=0.1, metadata=bounded(0, 100))
    """Spread of the samples around the surface (``surface_samples_offset``)."""
    truncation_m: float = field(default=0.2956502, metadata=bounded(0, 100, low_open=True))
    """Truncation distance of the SDF supervision (``trunc_distance``)."""
    truncation_weight: float = field(default=3.3834402, metadata=bounded(0, 1e6))
    """Weight of the truncated-SDF loss near the surface (``trunc_weight``)."""
    free_space_factor: float = field(default=5.0, metadata=bounded(0, 1e6))
    """Steepness of the free-space loss beyond the truncation (``free_space_factor``)."""
    loss_cap: float = field(default=2.0, metadata=bounded(0, 1e6, low_open=True))
    """Upper bound of the free-space loss per sample (``max_loss``)."""
    eikonal_weight: float = field(default=0.0268, metadata=bounded(0, 1e6))
    """Weight of the eikonal term (``eik_weight``)."""
    eikonal_apply_m: float = field(default=0.1, metadata=bounded(0, 100))
    """The eikonal term applies to samples at least this far from the surface (``eik_apply_dist``)."""
    lr: float = field(default=0.0013, metadata=bounded(0, 10, low_open=True))
    """Adam learning rate (``learning_rate``)."""
    weight_decay: float = field(default=0.012, metadata=bounded(0, 100))
    """Adam weight decay (``weight_decay``)."""
    iterations_first: int = field(default=200, metadata=bounded(0, 1_000_000))
    """The first frame is trained on this many iterations (``iters_first``), ..."""
    iterations_per_frame: int = field(default=3, metadata=bounded(1, 100_000))
    """... every frame after it on this many (``iters_per_frame``; MACIM's keyframes get 6) ..."""
    iterations_after: int = field(default=200, metadata=bounded(0, 1_000_000))
    """... and the map this many after the last frame (``iters_last``)."""

    def __post_init__(self) -> None:
        for name in ("width", "rays", "n_surface", "iterations_per_frame"):
            if getattr(self, name) < 1:
                raise ValueError(f"SdfConfig.{name} must be >= 1, got {getattr(self, name)}")
        if min(self.n_stratified, self.iterations_first, self.iterations_after) < 0:
            raise ValueError("SdfConfig.n_stratified, iterations_first and iterations_after must be >= 0")


@dataclass
class SdfSamples:
    """One step's samples: (R, S) ray depths and (R, S, 3) world points of R rays, and their (R, S) bounds."""

    depths: Tensor
    positions: Tensor
    bounds: Tensor


def sdf_samples(origins: Tensor, directions: Tensor, depth: Tensor, config: SdfConfig,
                generator: torch.Generator | None = None) -> SdfSamples:
    """MACIM's samples along R rays with valid depth ((R, 3) origins, directions with unit camera z,
    (R,) depth): d, n_surface - 1 from N(d, std), n_stratified stratified, all in [min, d + behind]."""
    r = depth.shape[0]
    far = depth + config.behind_surface_m
    noise = torch.randn(r, config.n_surface - 1, generator=generator, device=depth.device) * config.surface_std_m
    near_surface = torch.minimum(torch.clamp(depth[:, None] + noise, min=config.min_depth_m), far[:, None])
    u = torch.rand(r, config.n_stratified, generator=generator, device=depth.device)
    edges = torch.arange(config.n_stratified, device=depth.device)
    stratified = config.min_depth_m + (far - config.min_depth_m)[:, None] * (edges + u) / max(config.n_stratified, 1)
    depths = torch.cat([depth[:, None], near_surface, stratified], dim=1)
    positions = origins[:, None] + directions[:, None] * depths[..., None]
    return SdfSamples(depths, positions, batch_bounds(positions, positions[:, 0], depths, depth))


def batch_bounds(positions: Tensor, surface: Tensor, depths: Tensor, depth: Tensor) -> Tensor:
    """(R, S) distance of every sample to the nearest of the step's R surface points, negative where the
    sample lies behind its own ray's surface (iSDF's "pc" bounds: an upper bound on |sdf|)."""
    with torch.no_grad():
        r, s, _ = positions.shape
        # exact differences: the matrix-product form of cdist rounds distances by up to a millimetre
        nearest = torch.cdist(positions.reshape(1, r * s, 3), surface[None],
                              compute_mode="donot_use_mm_for_euclid_dist").amin(-1).reshape(r, s)
        return torch.where(depths > depth[:, None], -nearest, nearest)


def sdf_loss(sdf: Tensor, bounds: Tensor, config: SdfConfig) -> Tensor:
    """(R, S) per-sample SDF loss (before the mean): the truncation band's weighted L1 to the bound, free
    space's one-sided term, each capped at ``loss_cap``."""
    free = bounds > config.truncation_m
    free_term = torch.maximum(torch.relu(sdf - bounds), torch.exp(-config.free_space_factor * sdf) - 1.0)
    loss = torch.where(free, free_term, sdf - bounds).abs().clamp(max=config.loss_cap)
    return torch.where(free, loss, loss * config.truncation_weight)


def eikonal_loss(gradient: Tensor, bounds: Tensor, config: SdfConfig) -> Tensor:
    """(R, S) | |grad sdf| - 1 | times its weight, zero within ``eikonal_apply_m`` of a surface."""
    term = (gradient.norm(dim=-1) - 1.0).abs()
    return torch.where(bounds < config.eikonal_apply_m, torch.zeros_like(term), term) * config.eikonal_weight


def sdf_step_loss(signed_distance, samples: SdfSamples, config: SdfConfig) -> Tensor:
    """One step's loss: ``signed_distance`` ((R, S, 3) world points -> (R, S) metres) on the samples, the
    SDF loss plus the eikonal term on its gradient, averaged over every sample."""
    points = samples.positions.detach().requires_grad_(True)
    with torch.enable_grad():
        sdf = signed_distance(points)
        gradient, = torch.autograd.grad(sdf.sum(), points, create_graph=True)
    return (sdf_loss(sdf, samples.bounds, config) + eikonal_loss(gradient, samples.bounds, config)).mean()
