"""The env's settings: a preset of ``openmulti_env.presets`` (the same table ``openmulti run`` uses, so a
name means the same episode in both) with keyword overrides.

``rl`` (the default) and ``rl_tiny`` are the RL-sized presets; ``tiny``, ``demo``, ``fast`` and ``full`` are
the runs' episodes. Every field can be overridden by keyword (``parallel_env(..., rays_per_object=100)``);
an unknown keyword is an error listing the known ones.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from mapping.runtime import available_cores
from mapping.team import ChannelConfig, ExchangeConfig, TeamConfig
from mapping.team.consistency import CONSISTENCY_ALGORITHMS
from mapping.team.team import LEARNERS
from openmulti_env.presets import PRESET_NAMES, Preset, get_preset
from openmulti_env.world.world import MAX_AGENTS, WorldConfig

DEFAULT_PRESET = "rl"
REWARD_MODES = ("team", "individual")


@dataclass(frozen=True)
class EnvConfig:
    """Everything that shapes an episode of the env (one field per keyword override; the defaults are
    those of preset ``rl``, ``env_config`` takes another preset's)."""

    preset: str = DEFAULT_PRESET
    """The preset the other fields start from (``openmulti_env.presets``): its mapper settings beyond the
    fields below (e.g. meshing voxels) come with it."""
    scene: str = "room0"
    """Scene preset name, ``random:SEED`` or a manifest path."""
    num_agents: int = 4
    """Agents (2 to 8)."""
    frames_per_agent: int = 120
    """Frames on each agent's path; the episode ends when they are read."""
    image_width: int = 160
    """Camera image width in pixels."""
    image_height: int = 120
    """Camera image height in pixels."""
    planning_points: int = 6000
    """Surface samples the path planner reasons about."""
    culling_edge_m: float = 0.05
    """Granularity of the observable ground truth."""
    frames_per_round: int = 5
    """Frames each agent reads per env step."""
    keyframe_every: int = 5
    """Every this many frames is a keyframe (trained on)."""
    iterations_per_keyframe: int = 3
    """Local iterations of the data loss per keyframe."""
    rays_per_object: int = 48
    """Rays per object instance per iteration."""
    rays_per_structure: int = 96
    """Rays per wall / floor / ceiling per iteration."""
    refit_steps: int = 20
    """Distillation steps when an instance moves to a larger or agreed frame (a third of the run's 60)."""
    consistency: str = "consensus"
    """Parameter consistency (eq. 12): consensus, dinno, dsgd or none."""
    consistency_iterations: int = 1
    """Consistency iterations per step (data loss + eq. 12 + eq. 13)."""
    rays_per_pose: int = 64
    """Pixels a ray message replays per shared pose (eq. 13)."""
    cross_rendering: bool = True
    """Cross Rendering Supervision on shared rays (eq. 13)."""
    alignment: bool = True
    """Align arrived instances (False: adopt each as new)."""
    float16: bool = False
    """Parameter messages carry float16 vectors."""
    changed_only: float | None = None
    """Skip instances whose parameters moved less than this (relative) since last sent."""
    segmentation_errors: bool = True
    """The front end's seeded error model (False: perfect masks)."""
    success_probability: float = 1.0
    """Chance that each message arrives (drawn per message from the episode seed)."""
    comm_budget_mb: float | None = None
    """Megabytes each agent may send in an episode (None: unlimited)."""
    reward: str = "team"
    """``team``: every agent gets the team's gain; ``individual``: its own."""
    comm_cost_per_mb: float = 0.0
    """Reward cost per megabyte sent."""
    budget_penalty: float = 0.05
    """Reward penalty per message refused because its sender's budget was spent."""
    probe_points: int = 2000
    """Observable-surface samples the completion estimate probes (also the map channels' points)."""
    map_size: int = 64
    """Observation side in pixels (top-down map of the room)."""
    horizon: int | None = None
    """Steps before truncation (None: until the paths end). ``max_cycles`` is an alias."""
    text_encoder: str = "minilm"
    """Caption encoder of the front end: ``minilm`` (SBERT all-MiniLM-L6-v2, the paper's) or ``mpnet``."""
    device: str = "auto"
    """Learner device: cpu, cuda or auto."""
    threads: int | None = 1
    """Torch threads (None: all cores). One by default: the env's batches are small, several envs often
    share a machine, and a second thread waiting on a busy core slowed a ``tiny`` step 30x here."""
    agent_workers: int | None = None
    """Threads running the agents' learning side by side (None: one per core, at most one per agent);
    results do not depend on it."""
    learner: str = "per_agent"
    """``per_agent``: each agent trains on its own (on the worker threads); ``fleet``: every agent's steps
    batched into one computation (``mapping.fleet``; the same maps to float tolerance)."""
    agent_processes: str | None = None
    """``"ray"``: each agent's mapper in a process of its own (a Ray actor, ``mapping.team.remote``; the same
    maps and bytes on CPU); None: every agent in the env's process."""
    frame_cache_mb: float = 256.0
    """Rendered frames kept in memory across episodes (the paths repeat; past the cap frames are rendered)."""
    cache_dir: str | None = None
    """World-geometry cache folder (default: ``$OPENMULTI_CACHE`` or ``~/.cache/openmulti``, then ``worlds/``)."""
    cache_max_mb: float = 2048.0
    """Size cap of the world cache; the least recently used entries go first."""

    def validate(self) -> "EnvConfig":
        """Self, or ValueError naming the bad field."""
        if not 2 <= self.num_agents <= MAX_AGENTS:
            raise ValueError(f"num_agents must be between 2 and {MAX_AGENTS} (agents talk to peers), got {self.num_agents}")
        if self.reward not in REWARD_MODES:
            raise ValueError(f"reward must be one of {REWARD_MODES}, got {self.reward!r}")
        if self.consistency not in CONSISTENCY_ALGORITHMS:
            raise ValueError(f"consistency must be one of {CONSISTENCY_ALGORITHMS}, got {self.consistency!r}")
        if not 0.0 <= self.success_probability <= 1.0:
            raise ValueError(f"success_probability must be in [0, 1], got {self.success_probability}")
        if self.comm_budget_mb is not None and self.comm_budget_mb < 0:
            raise ValueError(f"comm_budget_mb must be >= 0 or None, got {self.comm_budget_mb}")
        if self.horizon is not None and self.horizon < 1:
            raise ValueError(f"horizon (max_cycles) must be >= 1 or None, got {self.horizon}")
        for name in ("frames_per_agent", "frames_per_round", "keyframe_every", "probe_points", "rays_per_pose"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.agent_workers is not None and self.agent_workers < 1:
            raise ValueError(f"agent_workers must be >= 1 or None, got {self.agent_workers}")
        if self.agent_processes not in (None, "ray"):
            raise ValueError(f"agent_processes must be None or 'ray', got {self.agent_processes!r}")
        if self.learner not in LEARNERS:
            raise ValueError(f"learner must be one of {LEARNERS}, got {self.learner!r}")
        if self.learner == "fleet" and self.agent_processes:
            raise ValueError("learner='fleet' batches agents in the env's process: not with agent_processes")
        if self.map_size < 8:
            raise ValueError(f"map_size must be at least 8 pixels, got {self.map_size}")
        return self

    # ---- what the parts are built from -----------------------------------------------------------
    def _preset_with_overrides(self) -> Preset:
        """The preset with this config's fields in place of its own."""
        base = get_preset(self.preset)
        mapping = replace(base.mapping, keyframe_every=self.keyframe_every,
                          iterations_per_keyframe=self.iterations_per_keyframe, rays_per_object=self.rays_per_object,
                          rays_per_structure=self.rays_per_structure, refit_steps=self.refit_steps)
        return replace(base, mapping=mapping, **{f: getattr(self, f) for f in _PRESET_FIELDS})

    def world_config(self) -> WorldConfig:
        return self._preset_with_overrides().world_config(self.num_agents)

    def team_config(self) -> TeamConfig:
        return self._preset_with_overrides().team_config(
            alignment=self.alignment,
            consistency={"algorithm": self.consistency, "cross_rendering": self.cross_rendering},
            exchange=ExchangeConfig(float16=self.float16, changed_only=self.changed_only))

    def workers(self) -> int:
        """Agent worker threads: ``agent_workers``, or one per core up to one per agent."""
        return self.agent_workers or max(1, min(self.num_agents, available_cores()))

    def channel_config(self) -> ChannelConfig:
        budget = None if self.comm_budget_mb is None else self.comm_budget_mb * 1e6
        return ChannelConfig(self.success_probability, budget)


_PRESET_FIELDS = ("frames_per_agent", "image_width", "image_height", "planning_points", "culling_edge_m",
                  "frames_per_round", "consistency_iterations", "rays_per_pose", "text_encoder", "scene", "num_agents",
                  "probe_points", "map_size")
"""EnvConfig fields that are ``Preset`` fields of the same name."""
_MAPPING_FIELDS = ("keyframe_every", "iterations_per_keyframe", "rays_per_object", "rays_per_structure", "refit_steps")
"""EnvConfig fields that are ``MappingConfig`` fields of the same name."""


def preset_fields(preset: Preset) -> dict:
    """The EnvConfig fields a preset sets."""
    return {**{f: getattr(preset, f) for f in _PRESET_FIELDS},
            **{f: getattr(preset.mapping, f) for f in _MAPPING_FIELDS}, "preset": preset.name}


FIELD_NAMES = tuple(f.name for f in fields(EnvConfig) if f.name != "preset")


def env_config(preset: str = DEFAULT_PRESET, **overrides) -> EnvConfig:
    """The preset's settings with ``overrides`` applied (``None`` values keep the preset's, except for
    the fields whose None means something: horizon, comm_budget_mb, changed_only, threads, cache_dir)."""
    if preset not in PRESET_NAMES:
        raise ValueError(f"unknown preset {preset!r}; choose one of {PRESET_NAMES}")
    unknown = sorted(set(overrides) - set(FIELD_NAMES))
    if unknown:
        raise TypeError(f"unknown env option(s) {unknown}; the options are {list(FIELD_NAMES)}")
    nullable = {"horizon", "comm_budget_mb", "changed_only", "threads", "cache_dir", "agent_workers", "agent_processes"}
    chosen = {k: v for k, v in overrides.items() if v is not None or k in nullable}
    return replace(EnvConfig(**preset_fields(get_preset(preset))), **chosen).validate()
