"""How one agent maps (``MappingConfig``): apart from the agent so that configs, presets and the
team's settings can name it without importing the mapper."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from mapping.config_fields import NEUTRAL_DEFAULT, bounded, lengths
from mapping.model.losses import DataLossWeights
from mapping.model.render import SamplerConfig
from mapping.model.sdf_loss import SdfConfig


FREE_SPACE_RAYS = ("box2d", "crossing")
"""Where an instance's free-space rays come from (``MappingConfig.free_space_rays``)."""


@dataclass(frozen=True)
class MappingConfig:
    """How one agent maps (vMAP's values unless said otherwise)."""

    keyframe_every: int = field(default=5, metadata=bounded(1, 10_000))
    """Every k-th frame becomes a keyframe (the first always does)."""
    iterations_per_keyframe: int = field(default=20, metadata=bounded(0, 10_000))
    """Optimisation steps after each keyframe (vMAP: 20 per frame)."""
    rays_per_object: int = field(default=120, metadata=bounded(1, 65_536))
    """Rays per object instance per step (vMAP: 120)."""
    rays_per_structure: int = field(default=300, metadata=bounded(1, 65_536))
    """Rays per wall / floor / ceiling instance per step (vMAP's background uses 1200 on a GPU; with
    the 128-wide network that alone is ~30 GFLOP a step, too slow for a 2-core CPU)."""
    own_ray_fraction: float = field(default=0.8, metadata=bounded(0, 1))
    """Share of an instance's rays on its own pixels; the rest on other surfaces in its 2D box."""
    free_space_rays: str = field(default="box2d", metadata=NEUTRAL_DEFAULT)
    """Where an instance's free-space rays (the ``1 - own_ray_fraction`` share) come from: ``box2d``, other
    surfaces inside the 2D box of its mask in keyframes that saw it (vMAP), or ``crossing``, any held
    keyframe's rays that enter its 3D box in front of their surface (``KeyframeBuffer.crossing_rays``)."""
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    """Samples per ray (vMAP: 1 stratified + 9 around the surface), inside each instance's box."""
    loss_weights: DataLossWeights = field(default_factory=DataLossWeights)
    """lambda_1..3 of eq. 11 (vMAP: occupancy 10, depth 1, colour 5)."""
    structure_width: int = field(default=64, metadata=bounded(1, 4096))
    """Hidden width of wall / floor / ceiling networks (vMAP's background: 128 on a GPU; planes need
    less, and at 128 they take 90% of a CPU step)."""
    structure_encoding_scale: float = field(default=2.0, metadata=bounded(0, 1000, low_open=True))
    """``FieldConfig.encoding_scale`` of the structure bank. A global map's one network lives in it
    with the scene box as its frame, where 2 leaves its finest geometry band a period of about 1.3 m
    (``mapping.team.global_map.GLOBAL_ENCODING_SCALE`` sets a finer one for it)."""
    lr: float = field(default=1e-3, metadata=bounded(0, 10, low_open=True))
    """AdamW learning rate."""
    object_voxel_m: float = field(default=0.01, metadata=bounded(0.001, 1))
    """Marching-cubes voxel for objects."""
    structure_voxel_m: float = field(default=0.02, metadata=bounded(0.001, 1))
    """Marching-cubes voxel for walls, floor and ceiling."""
    max_mesh_resolution: int = field(default=256, metadata=bounded(2, 2048))
    """Grid cap per axis (vMAP)."""
    keyframe_capacity: int = field(default=100, metadata=bounded(1, 100_000))
    """Keyframes held at once (memory bound; ``fast`` and ``full`` runs stay under it)."""
    keyframe_policy: str = "reservoir"
    """Which keyframe a new one replaces when the buffer is full: ``reservoir`` or ``window``."""
    frame_limit: float = field(default=2.0, metadata=bounded(0, 100, low_open=True))
    """An instance moves to a larger frame (refit by distillation) when its box reaches this far out
    of its frame's cube (``InstanceFieldBank.frame_coverage``)."""
    refit_steps: int = field(default=60, metadata=bounded(0, 100_000))
    """Distillation steps of such a move (batched over the instances that move together)."""
    global_frame: tuple[float, float, float, float] | None = field(
        default=None, metadata=lengths(4, 4, bounded(-1e4, 1e4)))
    """(centre x, y, z, half-size) given to every new instance instead of a frame from its first box:
    the scene box of a global map (``mapping.team.global_map``), fixed so that it is never refit."""
    structure_sdf: SdfConfig | None = field(default=None, metadata=NEUTRAL_DEFAULT)
    """Make the structure bank MACIM's scene SDF network, trained with its losses (``mapping.model.sdf_field``,
    ``mapping.model.sdf_loss``): the published form of the global baselines. None: vMAP's occupancy networks."""
    iterations_first_keyframe: int = field(default=0, metadata=bounded(0, 100_000, also=NEUTRAL_DEFAULT))
    """Extra local iterations in the round of an agent's first keyframe (MACIM: 200 on its first frame)."""
    iterations_after_stream: int = field(default=0, metadata=bounded(0, 100_000, also=NEUTRAL_DEFAULT))
    """Local iterations after an agent's last frame, on top of ``TeamConfig.min_local_steps`` (MACIM: 200)."""
    observed_cell_m: float | None = field(default=0.025, metadata=bounded(0, 1, low_open=True))
    """Cell of each instance's observed space (``mapping.model.observed``), sent with its parameters: meshes,
    rendered views, the env's observations and its reward hold surface only near cells where some keyframe's
    depth fell, i.e. within one to two cells of it. 2.5 cm keeps that inside the depth check's 5 cm (5 cm cells
    left room0 `demo` at 7.7 % of pixels off, 2.5 cm at 5.0 %; docs/observed_space.md). None: none kept, the
    networks drawn wherever they say (the tables recorded before issue 44; a global map keeps none:
    ``TeamConfig.global_map``)."""
    observed_ray_stride: int = field(default=16, metadata=bounded(1, 65_536))
    """Every n-th valid pixel of a keyframe marks its ray free in each instance box it crosses (with every
    4th pixel of the instance's own)."""

    def __post_init__(self) -> None:
        if self.observed_cell_m is not None and not (0 < self.observed_cell_m <= 1):
            raise ValueError(f"observed_cell_m must be in (0, 1] metres or None, got {self.observed_cell_m}")
        if self.observed_ray_stride < 1:
            raise ValueError(f"observed_ray_stride must be >= 1, got {self.observed_ray_stride}")
        if self.free_space_rays not in FREE_SPACE_RAYS:
            raise ValueError(f"unknown free_space_rays {self.free_space_rays!r}; choose one of {FREE_SPACE_RAYS}")


RECORDING_FREE_SPACE_WEIGHT = 10.0
"""``DataLossWeights.free_space`` on real recordings (``for_recordings``), as heavy as eq. 8's occupancy term."""
RECORDING_OWN_RAY_FRACTION = 0.5
"""``MappingConfig.own_ray_fraction`` on real recordings: half of an instance's rays are free-space ones."""
RECORDING_FREE_SPACE_RAYS = "crossing"
"""``MappingConfig.free_space_rays`` on real recordings: from any keyframe ray that crosses the instance's box."""


def for_recordings(config: MappingConfig) -> MappingConfig:
    """The mapper settings for a real RGB-D recording: ``config`` with empty-space carving on, and half of
    each instance's rays free-space ones taken from every keyframe ray that crosses its box. A setting
    ``config`` already moved from ``MappingConfig``'s default is kept.

    Why (``python -m studies.real_causes``, 7-Scenes and TUM, 2 agents, ``fast``, seeds 0 and 1): carving
    took the share of depth pixels off by > 5 cm from 30-56 % to 20-28 % and no seed collapsed into a
    box-filling blob; what stayed off was mostly surface an instance invented inside its box in front of
    another instance's surface, which only that other instance's rays saw. Free-space rays from every ray
    crossing the box, half of the rays, took it to 15-16 % (7-Scenes) and 20-22 % (TUM). The simulator's runs
    keep vMAP's loss and rays: their recorded tables were made with them (docs/real_data.md)."""
    default = MappingConfig()
    if not config.loss_weights.free_space:
        config = replace(config, loss_weights=replace(config.loss_weights, free_space=RECORDING_FREE_SPACE_WEIGHT))
    if config.own_ray_fraction == default.own_ray_fraction:
        config = replace(config, own_ray_fraction=RECORDING_OWN_RAY_FRACTION)
    if config.free_space_rays == default.free_space_rays:
        config = replace(config, free_space_rays=RECORDING_FREE_SPACE_RAYS)
    return config
