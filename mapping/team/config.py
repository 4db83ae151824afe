"""The settings that shape a team's learning: what consistency does, what messages carry, and the
team as a whole (one frozen dataclass each; ``mapping.team.member`` uses them)."""

from __future__ import annotations

from dataclasses import dataclass, field

from mapping.agent import MappingConfig
from mapping.fusion.online import OnlineFusionConfig
from mapping.team.arrival import ArrivalConfig


@dataclass(frozen=True)
class ConsistencyConfig:
    """How agents pull their maps together after an exchange."""

    algorithm: str = "consensus"
    """Parameter consistency (eq. 12): consensus (MACIM), dinno, dsgd or none."""
    rho: float = 0.3
    """Penalty weight (MACIM: 0.3; DiNNO: 0.3-0.5)."""
    iterations: int = 5
    """Consistency iterations per round (data loss + the terms below)."""
    cross_rendering: bool = True
    """Render consistency on the peers' shared rays (eq. 13)."""
    render_weight: float = 1.0
    """Weight of eq. 13 in the loss."""
    rays_per_pose: int = 256
    """Pixels replayed per shared pose."""
    poses_per_message: int = 2
    """Poses a ray message carries (the round's frames, evenly spread)."""
    samples_per_box: int = 16
    """Samples per crossed instance box when rendering shared rays."""
    free_space_weight: float = 0.0
    """Weight of eq. 13's optional free-space term (``render_consistency_loss``; 0: the plain L1)."""


@dataclass(frozen=True)
class ExchangeConfig:
    """What a parameter message carries."""

    float16: bool = False
    """Send network vectors and features as float16 (half the bytes)."""
    changed_only: float | None = None
    """Skip an instance whose parameters moved less than this (relative L2) since they last reached
    that peer; None sends every instance every time."""
    cloud_voxel_m: float = 0.02
    """Voxel of the clouds sent for alignment."""
    resend_cloud_growth: float = 2.0
    """Send an instance's cloud again when it has grown this many times since it last went."""
    forward_adopted: bool = False
    """Also send instances this agent only holds from peers (never saw itself): with every link up
    each peer has them from their owner already, so by default they are not forwarded."""
    point_clouds: bool = False
    """Point-cloud sharing (Table VI's baseline): a "send parameters" link carries the sender's
    observed points so far (``cloud_voxel_m`` down-sampled) instead; the receiver learns nothing from it."""


@dataclass(frozen=True)
class TeamConfig:
    """Everything that shapes a team's learning."""

    mapping: MappingConfig = field(default_factory=MappingConfig)
    fusion: OnlineFusionConfig = field(default_factory=OnlineFusionConfig)
    arrival: ArrivalConfig = field(default_factory=ArrivalConfig)
    consistency: ConsistencyConfig = field(default_factory=ConsistencyConfig)
    exchange: ExchangeConfig = field(default_factory=ExchangeConfig)
    frames_per_round: int = 5
    """Frames each agent reads per round (``fast``: one keyframe per round)."""
    alignment: bool = True
    """Align arrived instances (False: every arrived instance is adopted, the ablation)."""
    global_map: bool = False
    """One network for the whole scene (``mapping.team.global_map``) instead of one per instance: the
    global baselines. Set ``mapping.global_frame`` to the scene box with it."""
