"""The settings that shape a team's learning: what consistency does, what messages carry, and the
team as a whole (one frozen dataclass each; ``mapping.team.member`` uses them)."""

from __future__ import annotations

from dataclasses import dataclass, field

from mapping.config_fields import NEUTRAL_DEFAULT, bounded
from mapping.model.agent_config import MappingConfig
from mapping.fusion.online import OnlineFusionConfig
from mapping.team.arrival import ArrivalConfig
from mapping.team.consistency import MISSING_EDGES

CROSS_RENDERING_FORMS = ("instance", "composite")
"""The two forms of eq. 13 (``ConsistencyConfig.cross_rendering_form``)."""
RAY_POSES = ("current", "mapped")
"""Which views a ray message's poses come from (``ConsistencyConfig.ray_poses``)."""


@dataclass(frozen=True)
class ConsistencyConfig:
    """How agents pull their maps together after an exchange."""

    algorithm: str = "consensus"
    """Parameter consistency (eq. 12): consensus (MACIM), dinno, dsgd or none."""
    rho: float = field(default=3.0, metadata=bounded(0, 1e6))
    """Consensus penalty weight (MACIM used 0.3). With Adam the pull's step does not grow with rho, only
    its share of the gradient. Measured (room0 ``demo``, probe coverage, ``local_consensus``): rho 0.3
    90.6 %, rho 3 91.9 %."""
    dinno_rho: float = field(default=0.3, metadata=bounded(0, 1e6))
    """DiNNO's penalty weight (its paper: 0.3-0.5)."""
    missing_edges: str = "skip"
    """DiNNO and DSGD with a peer whose vector for an instance did not arrive this round: ``skip`` the
    edge this round (RAMEN skips the edges its channel dropped) or use the ``last`` vector held (the
    stale form: DiNNO's duals keep growing from an old difference, DSGD keeps mixing toward it).
    Consensus always uses the last vector held (MACIM). On a perfect link under ``always``, without
    changed-only sending, the two differ only on instances a peer stopped sending (e.g. merged away)."""
    iterations: int = field(default=5, metadata=bounded(0, 10_000))
    """Consistency iterations per round (data loss + the terms below)."""
    local_consensus: bool = True
    """With ``algorithm="consensus"``, also add the consensus penalty (eq. 12, toward the parameters last
    received) to every local iteration of the next round, as MACIM does at every step (False: eq. 12
    acts only in the ``iterations`` after an exchange; DiNNO and DSGD ignore it). Measured (room0
    ``demo``, probe coverage, rho 0.3): 90.6 % against 86.9 % without; the blind zones 87.9 against
    82.7 %, at no extra compute."""
    cross_rendering: bool = True
    """Render consistency on the peers' shared rays (eq. 13)."""
    cross_rendering_form: str = "composite"
    """How eq. 13 compares the two renderings: ``composite`` (the L1 of the two composited depths, the
    paper's) or ``instance`` (each of my instances a ray crosses is supervised like a keyframe ray, the
    peer's rendered depth and instance standing in for the sensor's depth and mask). Measured on room0
    ``demo`` (probe coverage of the room, mean of 4 agents, mapped poses, weight 1): composite 83.4 %,
    instance 58.3 %: the peer's rendered depth is within 5 cm of the truth on only 66-73 % of its rays,
    and the instance form stamps that error into my surfaces (floors thicken out of their boxes)."""
    blind_zones_only: bool = False
    """Eq. 13 only on shared rays whose peer surface none of my keyframes observed (my blind zones):
    where I saw the surface my data rules. Measured (room0 ``demo``, composite, mapped poses): 83.6 %
    against 83.4 % at weight 1, so off by default."""
    render_depth_uncertainty: bool = False
    """Weight eq. 13's depth errors by 1 / (sqrt(var) + 1e-4) as the data loss does (False: the paper's
    plain L1; the weight explodes where my map renders nothing yet)."""
    render_weight: float = field(default=0.3, metadata=bounded(0, 1e6))
    """Weight of eq. 13 in the loss. Measured (room0 ``demo``, mapped poses): 1.0 83.4 %, 0.3 86.9 %,
    0.1 86.8 % probe coverage; without eq. 13 86.1 %."""
    rays_per_pose: int = field(default=256, metadata=bounded(1, 65_536))
    """Pixels replayed per shared pose."""
    ray_poses: str = "mapped"
    """Which of its views a peer shares rays of: ``current`` (this round's frames, the paper's) or
    ``mapped`` (frames read before this round, drawn by the message's seed; this round's in the first:
    views its map has trained on, so that its rendering there is worth following). Measured (room0 ``demo``, weight 1): current
    79.2 %, mapped 83.4 % probe coverage; the peer's map of the frames it just read has had one
    round of training."""
    poses_per_message: int = field(default=2, metadata=bounded(1, 1024))
    """Poses a ray message carries (see ``ray_poses``)."""
    samples_per_box: int = field(default=16, metadata=bounded(1, 1024))
    """Samples per crossed instance box when rendering shared rays."""
    free_space_weight: float = field(default=0.0, metadata=bounded(0, 1e6))
    """Weight of eq. 13's optional free-space term (``render_consistency_loss``; 0: the plain L1)."""

    @property
    def penalty_rho(self) -> float:
        """The penalty weight of ``algorithm`` (``dinno_rho`` for DiNNO, else ``rho``)."""
        return self.dinno_rho if self.algorithm == "dinno" else self.rho

    def __post_init__(self) -> None:
        for name in ("rho", "dinno_rho"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.cross_rendering_form not in CROSS_RENDERING_FORMS:
            raise ValueError(f"unknown cross_rendering_form {self.cross_rendering_form!r}; "
                             f"choose one of {CROSS_RENDERING_FORMS}")
        if self.missing_edges not in MISSING_EDGES:
            raise ValueError(f"unknown missing_edges {self.missing_edges!r}; choose one of {MISSING_EDGES}")
        if self.ray_poses not in RAY_POSES:
            raise ValueError(f"unknown ray_poses {self.ray_poses!r}; choose one of {RAY_POSES}")


@dataclass(frozen=True)
class CodecConfig:
    """How a parameter message codes what it carries (docs/codec.md); the defaults code nothing.

    With the defaults every vector travels whole as float32, uncompressed, as before the codec existed
    (``mapping.team.codec``)."""

    bits: int = field(default=32, metadata=bounded(4, 32))
    """Bits of each network value sent: 32 (float32), 16 (float16), 8 or 4 (integers with a float32 scale per
    ``block`` values)."""
    feature_bits: int = field(default=32, metadata=bounded(4, 32))
    """Bits of each caption-feature value sent (as ``bits``)."""
    block: int = field(default=64, metadata=bounded(1, 65536))
    """Values that share one scale at 4 and 8 bits (a scale costs 4 bytes)."""
    delta: bool = False
    """Send the difference to the copy the receiver acknowledged (the first copy goes whole); the receiver
    adds it to its copy, so both ends hold the same vector."""
    keep: float = field(default=1.0, metadata=bounded(0, 1, low_open=True))
    """Share of a delta's entries sent, the largest first; the others stay in the next delta (error feedback:
    delayed, never lost). 1 sends them all."""
    cloud_bits: int = field(default=32, metadata=bounded(8, 32))
    """Bits of each cloud coordinate: 32 (float32), 16 or 8 (integers over the cloud's own box)."""
    leave_out_held: bool = True
    """With ``delta``, leave out a caption feature and an observed space the receiver holds unchanged (it keeps
    its copy)."""
    lossless: str = "none"
    """A lossless stage over the whole message: none, zlib or zstd."""

    def __post_init__(self) -> None:
        from mapping.team.codec import BITS, CLOUD_BITS  # noqa: PLC0415  (the codec's own tables)
        from mapping.team.wire import LOSSLESS  # noqa: PLC0415

        for name in ("bits", "feature_bits"):
            if getattr(self, name) not in BITS:
                raise ValueError(f"team.exchange.codec.{name} must be one of {BITS}, got {getattr(self, name)!r}")
        if self.cloud_bits not in CLOUD_BITS:
            raise ValueError(f"team.exchange.codec.cloud_bits must be one of {CLOUD_BITS}, got {self.cloud_bits!r}")
        if self.lossless not in LOSSLESS:
            raise ValueError(f"team.exchange.codec.lossless must be one of {LOSSLESS}, got {self.lossless!r}")
        if self.keep < 1.0 and not self.delta:
            raise ValueError("team.exchange.codec.keep < 1 leaves entries of a delta out: it needs "
                             "team.exchange.codec.delta=true")

    @property
    def active(self) -> bool:
        """Whether messages are coded at all (False: today's float32 format, bit for bit): some value travels in
        fewer bits, as a delta, or compressed (``block`` or ``leave_out_held`` alone code nothing)."""
        return (self.bits < 32 or self.feature_bits < 32 or self.cloud_bits < 32 or self.delta
                or self.lossless != "none")


@dataclass(frozen=True)
class ExchangeConfig:
    """What a parameter message carries."""


    float16: bool = False
    """Send network vectors and features as float16 (half the bytes)."""
    changed_only: float | None = field(default=None, metadata=bounded(0, 1e6))
    """Skip an instance whose parameters moved less than this (relative L2) since they last reached
    that peer; None sends every instance every time."""
    up_to_date_tolerance: float = field(default=0.05, metadata=bounded(0, 1e6))
    """A peer holds an instance up to date while its parameters moved less than this (relative L2) since
    they reached it (``AgentSnapshot.links``: what an agent knows of its peers' copies)."""
    cloud_voxel_m: float = field(default=0.02, metadata=bounded(0, 10, low_open=True))
    """Voxel of the clouds sent for alignment."""
    resend_cloud_growth: float = field(default=2.0, metadata=bounded(0, 1e6, low_open=True))
    """Send an instance's cloud again when it has grown this many times since it last went."""
    forward_adopted: bool = False
    """Also send instances this agent only holds from peers (never saw itself): with every link up
    each peer has them from their owner already, so by default they are not forwarded. DiNNO and DSGD
    always forward them (each agent shares its whole model, so every edge has both ends)."""
    point_clouds: bool = False
    """Point-cloud sharing (Table VI's baseline): a "send parameters" link carries the sender's
    observed points so far (``cloud_voxel_m`` down-sampled) instead; the receiver learns nothing from it."""
    codec: CodecConfig = field(default_factory=CodecConfig, metadata=NEUTRAL_DEFAULT)
    """How its vectors and its bytes are coded (``team.exchange.codec.*``)."""

    def __post_init__(self) -> None:
        if self.float16 and self.codec.active:
            raise ValueError("team.exchange.float16 and team.exchange.codec both set how vectors travel: give "
                             "team.exchange.codec.bits=16 instead of float16")


@dataclass(frozen=True)
class TeamConfig:
    """Everything that shapes a team's learning."""

    mapping: MappingConfig = field(default_factory=MappingConfig)
    fusion: OnlineFusionConfig = field(default_factory=OnlineFusionConfig)
    arrival: ArrivalConfig = field(default_factory=ArrivalConfig)
    consistency: ConsistencyConfig = field(default_factory=ConsistencyConfig)
    exchange: ExchangeConfig = field(default_factory=ExchangeConfig)
    frames_per_round: int = field(default=5, metadata=bounded(1, 100_000))
    """Frames each agent reads per round (``fast``: one keyframe per round)."""
    alignment: bool = True
    """Align arrived instances (False: every arrived instance is adopted, the ablation)."""
    global_map: bool = False
    """One network for the whole scene (``mapping.team.global_map``) instead of one per instance: the
    global baselines. Set ``mapping.global_frame`` to the scene box with it."""
    shared_global_init: bool = True
    """With ``global_map``, every agent's network starts from the same parameters (agent 0's), as MACIM
    deep-copies robot 0's map to every robot and DiNNO starts every node from one base model: eq. 12 and
    DiNNO average networks of one origin. False: each agent draws its own (the rows made before
    2026-12-05). Instance-level maps keep one draw per agent: an agent draws an instance's network when it
    first sees the instance."""
    min_keyframes: int = field(default=0, metadata=bounded(0, 100_000))
    """Keyframes each agent's map takes at least from its stream: a stream shorter than a full path of the
    preset takes one every ``len(stream) // min_keyframes`` frames (down to every frame) instead of every
    ``keyframe_every``. The presets set it to what a full path of theirs gives, so the simulator's runs take
    their keyframes as without it. Measured (TUM fr3 cabinet, 29 frames 15 cm apart per agent at ``fast``):
    every frame a keyframe cut the depth check's off share from 72 to 40 %."""
    min_local_steps: int = field(default=0, metadata=bounded(0, 1_000_000_000))
    """Local iterations each agent's map gets at least over its stream: an agent whose stream ends after
    fewer keyframes (a short recording, held-out frames) runs the rest after its last frame, as MACIM
    trains 200 iterations after its last frame. The presets set it to what a full path of theirs gets, so
    the simulator's runs, whose paths are full, train exactly as without it (unless frames are held out:
    ``holdout_every`` then gets the steps its held-out keyframes would have had). Measured (7-Scenes, 25 frames
    per agent at ``fast``): 5x the local iterations cut the depth check's off share from 49 to 27 %."""
    holdout_every: int | None = field(default=None, metadata=bounded(2, 100_000))
    """Keep every k-th frame of each agent's stream (stream positions k-1, 2k-1, ...) out of its map: neither
    fused nor trained on, so the depth check can score views the map never saw. None: every frame mapped."""

    def __post_init__(self) -> None:
        for name in ("min_keyframes", "min_local_steps"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.holdout_every is not None and self.holdout_every < 2:
            raise ValueError(f"holdout_every must be >= 2 (or None), got {self.holdout_every}")
        if self.mapping.structure_sdf is not None and self.consistency.cross_rendering:
            raise ValueError("Cross Rendering (eq. 13) renders the peers' occupancy fields; MACIM's scene SDF "
                             "(mapping.structure_sdf, the published global form) has none: set "
                             "consistency.cross_rendering=False (MACIM and Di-NeRF* use none)")

    def keyframe_every(self, stream_length: int) -> int:
        """The keyframe interval of an agent whose stream has ``stream_length`` frames (``min_keyframes``)."""
        every = self.mapping.keyframe_every
        return every if self.min_keyframes == 0 else max(1, min(every, stream_length // self.min_keyframes))

    def held_out(self, position: int) -> bool:
        """Whether the frame at this position of an agent's stream is kept out of its map."""
        return self.holdout_every is not None and position % self.holdout_every == self.holdout_every - 1
