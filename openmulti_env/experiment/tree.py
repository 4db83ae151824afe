"""The configuration tree of one experiment: every setting of a run, of the env and of training, in one
frozen dataclass tree.

    Experiment
      preset, scene, seed                  what the episode is
      world       WorldConfig               agents, paths, sensor, free space, culling (``openmulti_env.world``)
      perception  PerceptionSettings        the front end: error model, text and image encoders, segmenter
      team        TeamConfig                the learner: mapping, fusion, arrival, consistency, exchange, ...
      global_map  GlobalMapSettings         the global baselines' one network (with ``team.global_map``)
      channel     ChannelConfig             the links: success probability, byte budget
      env         EnvSettings               the PettingZoo env only: reward, observation, horizon, caches
      run         RunSettings               how the job runs: policy, output, threads, checkpoints, scoring
      data        DataSettings              a real RGB-D data set instead of the simulator (``data.path``)

A preset (``openmulti_env.experiment.presets``) is one such tree; every entry point (``openmulti run``, ``reproduce``'s
methods, ``parallel_env(**overrides)``, ``openmulti train``) builds its tree as a preset plus overrides
(``openmulti_env.experiment.overrides``), each option is written once (its docstring is its ``--help``), and
every run writes its tree whole (``openmulti_env.experiment.files``) so that ``--config`` repeats it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from mapping.config_fields import NEUTRAL_DEFAULT, bounded
from mapping.model.sdf_loss import SdfConfig
from mapping.pipeline.settings import RunSettings
from mapping.team import ChannelConfig, TeamConfig
from mapping.team.global_map import GLOBAL_ENCODING_SCALE, GLOBAL_WIDTH
from openmulti_env.world.world import WorldConfig

DEFAULT_PRESETS = {"run": "fast", "reproduce": "fast", "env": "rl", "train": "rl_small"}
"""The preset each entry point starts from when none is given: ``openmulti run`` and ``reproduce`` the measured
setting, ``parallel_env`` the RL-sized one, ``openmulti train`` the one it learns at. ``Experiment()`` itself is
``fast`` (``openmulti_env.experiment.presets``). A study names its own (the setting its rows were measured at)."""
TEXT_ENCODERS = ("mpnet", "minilm")
REWARD_MODES = ("team", "individual")
REWARD_BASELINES = ("none", "never_always", "front")
"""``env.reward_baseline``: raw gains, gains over the same episode's never/always (environment.rewards), or
those gains less the price of bytes on the episode's fixed-rate front (environment.reward_front)."""
DATA_KINDS = ("auto", "replica", "nice_slam", "scannet")
PROCESS_MODES = (None, "ray")


@dataclass(frozen=True)
class PerceptionSettings:
    """The front end (sec. III-A): what turns frames into instance observations."""

    segmentation_errors: bool = True
    """The simulator's seeded error model of the segmenter and captioner (False: perfect masks)."""
    text_encoder: str = "mpnet"
    """Caption encoder: ``mpnet`` (SBERT all-mpnet-base-v2) or ``minilm`` (all-MiniLM-L6-v2, OpenObj's)."""
    clip_checkpoint: str | None = None
    """Local open_clip checkpoint: masks get visual features (None: caption features only)."""
    segmenter: str = "fixed"
    """The geometric segmenter's thresholds for data without instance images: ``fixed`` or ``range_aware``."""


@dataclass(frozen=True)
class GlobalMapSettings:
    """The global baselines' one network per agent (used when ``team.global_map`` is set)."""

    form: str = "equal_compute"
    """``equal_compute`` (an occupancy network with the instance-level map's per-step FLOPs) or
    ``published`` (MACIM's scene SDF, samples, losses, iteration budget and rho 0.3)."""
    width: int = field(default=GLOBAL_WIDTH, metadata=bounded(1, 4096))
    """Hidden width of the equal-compute network (the published form uses ``sdf.width``)."""
    encoding_scale: float = field(default=GLOBAL_ENCODING_SCALE, metadata=bounded(0, 1000, low_open=True))
    """Positional-encoding scale of the equal-compute network in the scene box."""
    sdf: SdfConfig = field(default_factory=SdfConfig)
    """The published form's settings (MACIM's by default)."""


@dataclass(frozen=True)
class EnvSettings:
    """What only the PettingZoo env uses: reward, observation, horizon and its caches."""

    reward: str = "team"
    """``team``: every agent gets the team's completion gain; ``individual``: its own."""
    comm_cost_per_mb: float = field(default=0.01, metadata=bounded(0, 1e6))
    """Reward cost per megabyte sent (0: free bytes, and ``always`` is optimal by construction). 0.01 was chosen
    at ``rl_small``, where it puts the best fixed schedule inside the range (per agent: ``always`` 0.24,
    ``every:3`` 0.39, ``never`` 0.14; docs/schedules.md)."""
    reward_baseline: str = field(default="none", metadata=NEUTRAL_DEFAULT)
    """``none``: the raw completion gain; ``never_always``: each step's gain less ``never``'s at that step, over
    what ``always`` adds by the end, in the same world and episode (both played once and cached): the same scale
    in every world (``openmulti_env.environment.rewards``). ``comm_cost_per_mb`` is then not used. ``front``
    (team reward only): the same gains less what the episode's fixed-rate front completes more at the team's
    bytes after the step than before it, so the return is the margin over that front
    (``openmulti_env.environment.reward_front``); ``comm_cost_per_mb`` and ``comm_cost_of_always`` are not used."""
    comm_cost_of_always: float = field(default=0.3, metadata=bounded(0, 1e6, also=NEUTRAL_DEFAULT))
    """With ``reward_baseline="never_always"``: the return's price of sending as many bytes as ``always`` does in
    that world (``always`` returns 1 minus this, ``never`` 0)."""
    action_form: str = "entries"
    """``entries`` (per peer: parameters, rays), ``round`` (one decision per round) or ``instances`` (per peer:
    which of ``instance_slots`` instances, then rays; ``openmulti_env.environment.actions``)."""
    instance_slots: int = field(default=16, metadata=bounded(1, 256))
    """Slots per peer of the ``instances`` action form and observation (its instances in priority order)."""
    budget_penalty: float = field(default=0.05, metadata=bounded(0, 1e6))
    """Reward penalty per message refused because its sender's budget was spent."""
    probe_points: int = field(default=2000, metadata=bounded(1, 10_000_000))
    """Observable-surface samples of the completion estimate (reward; also the map channels' points)."""
    map_size: int = field(default=64, metadata=bounded(8, 4096))
    """Observation side in pixels (top-down map of the room)."""
    horizon: int | None = field(default=None, metadata=bounded(1, 100_000))
    """Steps before truncation (None: until the paths end, which is termination). ``max_cycles`` is an alias."""
    frame_cache_mb: float = field(default=256.0, metadata=bounded(0, 1e7))
    """Rendered frames kept in memory across episodes (past the cap frames are rendered again)."""
    cache_dir: str | None = None
    """World-geometry cache folder (default: ``$OPENMULTI_CACHE`` or ``~/.cache/openmulti``, then ``worlds/``)."""
    cache_max_mb: float = field(default=2048.0, metadata=bounded(0, 1e9))
    """Size cap of the world cache; the least recently used entries go first."""
    episode: str = "real"
    """``real``: every step runs the mapper; ``recorded``: each episode replays one of ``recordings`` real episodes
    (recorded once per world and cached beside the world cache) and models what the actions change
    (``mapping.team.recorded``, docs/recorded.md): the same spaces, actions, rewards and infos, milliseconds a step."""
    recordings: int = field(default=4, metadata=bounded(1, 10_000))
    """With ``episode="recorded"``: real episodes recorded per world; ``reset(seed)`` picks one by its episode seed
    (the channel's draws still follow the episode seed)."""


@dataclass(frozen=True)
class DataSettings:
    """A real RGB-D data set instead of the simulator (``path`` None: the simulator)."""

    path: str | None = None
    """The data set folder (Replica vMAP or NICE-SLAM layout, or a ScanNet export), cut into one contiguous
    sequence per agent."""
    kind: str = "auto"
    """Data set layout: auto, replica, nice_slam or scannet."""
    gt_mesh: str | None = None
    """Ground-truth mesh (None: a TSDF reference of the frames)."""
    frames: str | None = None
    """``A:B:S``: frames A..B-1 every S-th, before the split into agents."""
    intrinsics: str | None = None
    """``FX,FY,CX,CY``: override the data set's camera."""
    depth_scale: float | None = field(default=None, metadata=bounded(0, 1e9, low_open=True))
    """Raw depth units per metre (None: the layout's or cam_params.json)."""
    recording_mapper: bool = True
    """The mapper through ``mapping.model.agent_config.for_recordings`` (carving, crossing free-space rays)."""


@dataclass(frozen=True)
class Experiment:
    """Every setting of one experiment (see the module docstring)."""

    preset: str = DEFAULT_PRESETS["run"]
    """The preset this tree started from (``openmulti_env.experiment.presets``); recorded, not read by the parts."""
    scene: str = "room0"
    """Scene preset name, ``random:SEED`` or the path of a scene manifest."""
    seed: int = field(default=0, metadata=bounded(0, 2**32 - 1))
    """One seed for layout, paths, segmentation errors, channel draws and network initialisation."""
    world: WorldConfig = field(default_factory=WorldConfig)
    perception: PerceptionSettings = field(default_factory=PerceptionSettings)
    team: TeamConfig = field(default_factory=TeamConfig)
    global_map: GlobalMapSettings = field(default_factory=GlobalMapSettings)
    channel: ChannelConfig = field(default_factory=ChannelConfig)
    env: EnvSettings = field(default_factory=EnvSettings)
    run: RunSettings = field(default_factory=RunSettings)
    data: DataSettings = field(default_factory=DataSettings)

    @property
    def num_agents(self) -> int:
        """The team size (``world.num_agents``)."""
        return self.world.num_agents

    def with_team_minimums(self) -> "Experiment":
        """The tree with ``team.min_keyframes`` and ``team.min_local_steps`` set to what a full path of
        ``world.path.frames_per_agent`` frames gives (floor, so that a full path's keyframe interval is never
        below ``keyframe_every``): a short stream still gets a full path's keyframes and iterations."""
        mapping = self.team.mapping
        keyframes = self.world.path.frames_per_agent // mapping.keyframe_every
        return replace(self, team=replace(self.team, min_keyframes=keyframes,
                                          min_local_steps=keyframes * mapping.iterations_per_keyframe))
