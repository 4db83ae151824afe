"""The one table of presets: how big an episode is and how hard the learner works, for ``openmulti run``,
``openmulti reproduce``, the benchmarks, ``openmulti train`` and ``parallel_env`` alike. Each preset is a whole
configuration tree (``openmulti_env.experiment.Experiment``); every entry point starts from one and applies its
overrides, so a name means the same episode everywhere (scene presets such as ``room0`` are another thing, in
``openmulti_env.world.presets``).

| preset    | frames / agent | image   | frames / round | keyframe | iterations / keyframe | text encoder |
|-----------|----------------|---------|----------------|----------|-----------------------|--------------|
| `tiny`    | 24             | 160x120 | 4              | every 4  | 10                    | MPNet        |
| `demo`    | 120            | 320x240 | 10             | every 10 | 20                    | MPNet        |
| `fast`    | 120            | 320x240 | 5              | every 5  | 20                    | MPNet        |
| `full`    | 200            | 320x240 | 10             | every 2  | 20                    | MPNet        |
| `rl_tiny` | 16             | 80x60   | 2              | every 2  | 1                     | MiniLM       |
| `rl_small`| 60             | 80x60   | 5              | every 5  | 3                     | MiniLM       |
| `rl_lite` | 36             | 80x60   | 3              | every 3  | 1                     | MiniLM       |
| `rl`      | 120            | 160x120 | 5              | every 5  | 3                     | MiniLM       |

``full`` is the paper's setting, ``fast`` the measured one, ``demo`` the paths of ``fast`` with half the
keyframes and coarser meshes (``make demo`` in about 5 minutes here), ``tiny`` for smoke runs and tests.
``rl``, ``rl_small`` and ``rl_tiny`` are RL-sized: a few iterations per step and the small MiniLM encoder.
``rl`` (the env's default) is 24 steps of a few seconds; ``rl_small`` (12 steps of 1-2 s) is where
``openmulti train`` learns: there ``always``, ``never`` and fixed-rate schedules end points apart
(``benchmarks/bench_schedules.py``); ``rl_lite`` is 12 steps as well with 40 % fewer frames (so shorter tours: the
planner takes at most a third of the frames as key views, 12 against 20, about 30 % less path), one iteration per
keyframe, half the rays and a quarter of the refit steps (issue 47: about 1.5x the env steps an hour; whether it
ranks schedules as ``fast`` does is ``benchmarks/transfer_check.py --cheap rl_lite``, docs/transfer.md);
``rl_tiny`` (a tenth of a second a step) is for tests.
"""

from __future__ import annotations

from dataclasses import replace

from mapping.model.agent_config import MappingConfig
from mapping.team import ConsistencyConfig, TeamConfig
from openmulti_env.experiment.tree import EnvSettings, Experiment, PerceptionSettings
from openmulti_env.world.paths import PathConfig
from openmulti_env.world.sensor import SensorConfig
from openmulti_env.world.world import WorldConfig


def _preset(name: str, mapping: MappingConfig, frames_per_agent: int = 120, image: tuple[int, int] = (320, 240),
            planning_points: int = 6000, culling_edge_m: float = 0.05, frames_per_round: int = 5,
            consistency_iterations: int = ConsistencyConfig.iterations,
            rays_per_pose: int = ConsistencyConfig.rays_per_pose, text_encoder: str = "mpnet", scene: str = "room0",
            num_agents: int = 4, probe_points: int = 2000, map_size: int = 64) -> Experiment:
    """One row of the table as a tree (the arguments are the columns that differ between presets)."""
    tree = Experiment(
        preset=name, scene=scene,
        world=WorldConfig(num_agents=num_agents,
                          path=PathConfig(frames_per_agent=frames_per_agent, planning_points=planning_points),
                          sensor=SensorConfig(width=image[0], height=image[1]), culling_edge_m=culling_edge_m),
        perception=PerceptionSettings(text_encoder=text_encoder),
        team=TeamConfig(mapping=mapping, frames_per_round=frames_per_round,
                        consistency=ConsistencyConfig(iterations=consistency_iterations, rays_per_pose=rays_per_pose)),
        env=EnvSettings(probe_points=probe_points, map_size=map_size))
    return tree.with_team_minimums()


PRESETS: dict[str, Experiment] = {p.preset: p for p in (
    _preset("tiny", MappingConfig(keyframe_every=4, iterations_per_keyframe=10, rays_per_object=60,
                                  rays_per_structure=120, object_voxel_m=0.02, structure_voxel_m=0.04, refit_steps=20),
            frames_per_agent=24, image=(160, 120), planning_points=2000, culling_edge_m=0.1, frames_per_round=4,
            consistency_iterations=2, rays_per_pose=64),
    _preset("demo", MappingConfig(keyframe_every=10, iterations_per_keyframe=20, object_voxel_m=0.02,
                                  structure_voxel_m=0.03), frames_per_round=10),
    _preset("fast", MappingConfig(keyframe_every=5, iterations_per_keyframe=20)),
    _preset("full", MappingConfig(keyframe_every=2, iterations_per_keyframe=20), frames_per_agent=200,
            frames_per_round=10, probe_points=10000, map_size=96),
    _preset("rl_tiny", MappingConfig(keyframe_every=2, iterations_per_keyframe=1, rays_per_object=24,
                                     rays_per_structure=48, refit_steps=10),
            frames_per_agent=16, image=(80, 60), planning_points=1500, culling_edge_m=0.1, frames_per_round=2,
            consistency_iterations=1, rays_per_pose=24, text_encoder="minilm", scene="tiny", num_agents=2,
            probe_points=600, map_size=48),
    _preset("rl_small", MappingConfig(keyframe_every=5, iterations_per_keyframe=3, rays_per_object=48,
                                      rays_per_structure=96, refit_steps=20),
            frames_per_agent=60, image=(80, 60), consistency_iterations=1, rays_per_pose=64, text_encoder="minilm",
            map_size=48),
    _preset("rl_lite", MappingConfig(keyframe_every=3, iterations_per_keyframe=1, rays_per_object=24,
                                     rays_per_structure=48, refit_steps=5),
            frames_per_agent=36, image=(80, 60), frames_per_round=3, consistency_iterations=1, rays_per_pose=32,
            text_encoder="minilm", map_size=48),
    _preset("rl", MappingConfig(keyframe_every=5, iterations_per_keyframe=3, rays_per_object=48,
                                rays_per_structure=96, refit_steps=20),
            image=(160, 120), consistency_iterations=1, rays_per_pose=64, text_encoder="minilm"),
)}
PRESET_NAMES = tuple(PRESETS)
PRESET_SUMMARIES: dict[str, str] = {
    "tiny": "smoke runs and tests: 24 frames per agent at 160x120",
    "demo": "make demo: fast's paths, a keyframe every 10th frame, 2 cm / 3 cm meshes",
    "fast": "the measured setting: 120 frames per agent, a keyframe every 5th, 20 iterations each",
    "full": "the paper's setting: 200 frames per agent, a keyframe every 2nd",
    "rl_tiny": "RL tests: 2 agents in the tiny room, 16 frames at 80x60, 1 iteration per keyframe",
    "rl_small": "RL training: 60 frames per agent at 80x60 (12 steps), where schedules end points apart",
    "rl_lite": "cheaper training: 12 steps of 36 frames (shorter tours), 1 iteration per keyframe, half the rays",
    "rl": "RL-sized: room0, 120 frames at 160x120, 3 iterations per keyframe, about a second per step",
}
"""One line per preset for ``--help`` and the docs."""


def get_preset(name: str) -> Experiment:
    """The preset called ``name`` (ValueError naming the known ones)."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {PRESET_NAMES}")
    return PRESETS[name]


def world_config(preset: str, num_agents: int) -> WorldConfig:
    """The preset's simulated world for ``num_agents`` agents."""
    return replace(get_preset(preset).world, num_agents=num_agents)


def mapping_config(preset: str) -> MappingConfig:
    """The preset's mapper settings."""
    return get_preset(preset).team.mapping


def team_config(preset: str, mapping: MappingConfig | None = None, consistency: dict | None = None,
                **options) -> TeamConfig:
    """The preset's team settings; ``mapping`` replaces its mapper settings (the minimums follow it),
    ``consistency`` holds ``ConsistencyConfig`` fields to change, ``options`` other ``TeamConfig`` fields."""
    tree = get_preset(preset)
    if mapping is not None:
        tree = replace(tree, team=replace(tree.team, mapping=mapping)).with_team_minimums()
    team = replace(tree.team, consistency=replace(tree.team.consistency, **(consistency or {})))
    return replace(team, **options)
