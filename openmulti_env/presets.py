"""The one table of presets: how big an episode is and how hard the learner works, for ``openmulti run``,
``openmulti reproduce``, the benchmarks and ``parallel_env`` alike (a name means the same episode
everywhere; scene presets such as ``room0`` are another thing, in ``openmulti_env.world.presets``).

| preset    | frames / agent | image   | frames / round | keyframe | iterations / keyframe | text encoder |
|-----------|----------------|---------|----------------|----------|-----------------------|--------------|
| `tiny`    | 24             | 160x120 | 4              | every 4  | 10                    | MPNet        |
| `demo`    | 120            | 320x240 | 10             | every 10 | 20                    | MPNet        |
| `fast`    | 120            | 320x240 | 5              | every 5  | 20                    | MPNet        |
| `full`    | 200            | 320x240 | 10             | every 2  | 20                    | MPNet        |
| `rl_tiny` | 16             | 80x60   | 2              | every 2  | 1                     | MiniLM       |
| `rl_small`| 60             | 80x60   | 5              | every 5  | 3                     | MiniLM       |
| `rl`      | 120            | 160x120 | 5              | every 5  | 3                     | MiniLM       |

``full`` is the paper's setting, ``fast`` the measured one, ``demo`` the paths of ``fast`` with half the
keyframes and coarser meshes (``make demo`` in about 5 minutes here), ``tiny`` for smoke runs and tests.
``rl``, ``rl_small`` and ``rl_tiny`` are RL-sized: a few iterations per step and the small MiniLM encoder.
``rl`` (the env's default) is 24 steps of a few seconds; ``rl_small`` (12 steps of 1-2 s) is where
``openmulti train`` learns: there ``always``, ``never`` and fixed-rate schedules end points apart
(``benchmarks/bench_schedules.py``); ``rl_tiny`` (a tenth of a second a step) is for tests.
"""

from __future__ import annotations

from dataclasses import dataclass

from mapping.agent_config import MappingConfig
from mapping.team import ConsistencyConfig, TeamConfig
from openmulti_env.world.paths import PathConfig
from openmulti_env.world.sensor import SensorConfig
from openmulti_env.world.world import WorldConfig


@dataclass(frozen=True)
class Preset:
    """One named episode size: the world, the mapper and team effort, the text encoder, the env's maps."""

    name: str
    summary: str
    """One line for ``--help`` and the docs."""
    mapping: MappingConfig
    """The mapper's settings (keyframes, iterations, rays, meshing voxels)."""
    frames_per_agent: int = 120
    """Frames on each agent's path; the run (episode) ends when they are read."""
    image_width: int = 320
    """Camera image width in pixels."""
    image_height: int = 240
    """Camera image height in pixels."""
    planning_points: int = 6000
    """Surface samples the path planner reasons about."""
    culling_edge_m: float = 0.05
    """Granularity of the observable ground truth (faces split to this edge before culling)."""
    frames_per_round: int = 5
    """Frames each agent reads per round (env step)."""
    consistency_iterations: int = ConsistencyConfig.iterations
    """Consistency iterations (eq. 12 + 13) per round."""
    rays_per_pose: int = ConsistencyConfig.rays_per_pose
    """Pixels a ray message replays per shared pose (eq. 13)."""
    text_encoder: str = "mpnet"
    """Caption encoder of the front end: ``mpnet`` (all-mpnet-base-v2) or ``minilm`` (all-MiniLM-L6-v2)."""
    scene: str = "room0"
    """Default scene of the env."""
    num_agents: int = 4
    """Default number of agents of the env."""
    probe_points: int = 2000
    """Env only: observable-surface samples of the completion estimate (reward)."""
    map_size: int = 64
    """Env only: observation side in pixels."""

    def world_config(self, num_agents: int) -> WorldConfig:
        """The simulated world of this preset for ``num_agents`` agents."""
        return WorldConfig(num_agents=num_agents,
                           path=PathConfig(frames_per_agent=self.frames_per_agent, planning_points=self.planning_points),
                           sensor=SensorConfig(width=self.image_width, height=self.image_height),
                           culling_edge_m=self.culling_edge_m)

    def team_config(self, mapping: MappingConfig | None = None, consistency: dict | None = None,
                    **options) -> TeamConfig:
        """The team settings; ``mapping`` replaces the preset's mapper settings, ``consistency`` holds
        ``ConsistencyConfig`` fields (the preset's iterations and rays per pose unless given), ``options``
        set other ``TeamConfig`` fields."""
        consistency = ConsistencyConfig(**{"iterations": self.consistency_iterations,
                                           "rays_per_pose": self.rays_per_pose, **(consistency or {})})
        mapping = mapping or self.mapping
        # floor, so that a full path's interval (frames // this) is never below keyframe_every
        full_path_keyframes = self.frames_per_agent // mapping.keyframe_every
        return TeamConfig(mapping=mapping, frames_per_round=self.frames_per_round, consistency=consistency,
                          **{"min_keyframes": full_path_keyframes,
                             "min_local_steps": full_path_keyframes * mapping.iterations_per_keyframe, **options})


PRESETS: dict[str, Preset] = {p.name: p for p in (
    Preset("tiny", "smoke runs and tests: 24 frames per agent at 160x120",
           MappingConfig(keyframe_every=4, iterations_per_keyframe=10, rays_per_object=60, rays_per_structure=120,
                         object_voxel_m=0.02, structure_voxel_m=0.04, refit_steps=20),
           frames_per_agent=24, image_width=160, image_height=120, planning_points=2000, culling_edge_m=0.1,
           frames_per_round=4, consistency_iterations=2, rays_per_pose=64),
    Preset("demo", "make demo: fast's paths, a keyframe every 10th frame, 2 cm / 3 cm meshes",
           MappingConfig(keyframe_every=10, iterations_per_keyframe=20, object_voxel_m=0.02, structure_voxel_m=0.03),
           frames_per_round=10),
    Preset("fast", "the measured setting: 120 frames per agent, a keyframe every 5th, 20 iterations each",
           MappingConfig(keyframe_every=5, iterations_per_keyframe=20)),
    Preset("full", "the paper's setting: 200 frames per agent, a keyframe every 2nd",
           MappingConfig(keyframe_every=2, iterations_per_keyframe=20), frames_per_agent=200, frames_per_round=10,
           probe_points=10000, map_size=96),
    Preset("rl_tiny", "RL tests: 2 agents in the tiny room, 16 frames at 80x60, 1 iteration per keyframe",
           MappingConfig(keyframe_every=2, iterations_per_keyframe=1, rays_per_object=24, rays_per_structure=48,
                         refit_steps=10),
           frames_per_agent=16, image_width=80, image_height=60, planning_points=1500, culling_edge_m=0.1,
           frames_per_round=2, consistency_iterations=1, rays_per_pose=24, text_encoder="minilm", scene="tiny",
           num_agents=2, probe_points=600, map_size=48),
    Preset("rl_small", "RL training: 60 frames per agent at 80x60 (12 steps), where schedules end points apart",
           MappingConfig(keyframe_every=5, iterations_per_keyframe=3, rays_per_object=48, rays_per_structure=96,
                         refit_steps=20),
           frames_per_agent=60, image_width=80, image_height=60, consistency_iterations=1, rays_per_pose=64,
           text_encoder="minilm", map_size=48),
    Preset("rl", "RL-sized: room0, 120 frames at 160x120, 3 iterations per keyframe, about a second per step",
           MappingConfig(keyframe_every=5, iterations_per_keyframe=3, rays_per_object=48, rays_per_structure=96,
                         refit_steps=20),
           image_width=160, image_height=120, consistency_iterations=1, rays_per_pose=64, text_encoder="minilm"),
)}
PRESET_NAMES = tuple(PRESETS)


def get_preset(name: str) -> Preset:
    """The preset called ``name`` (ValueError naming the known ones)."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {PRESET_NAMES}")
    return PRESETS[name]


def world_config(preset: str, num_agents: int) -> WorldConfig:
    """``get_preset(preset).world_config(num_agents)``."""
    return get_preset(preset).world_config(num_agents)


def mapping_config(preset: str) -> MappingConfig:
    """The preset's mapper settings."""
    return get_preset(preset).mapping


def team_config(preset: str, **options) -> TeamConfig:
    """``get_preset(preset).team_config(**options)``."""
    return get_preset(preset).team_config(**options)
