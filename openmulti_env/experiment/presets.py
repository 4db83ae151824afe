"""The one table of presets: how big an episode is and how hard the learner works, for ``openmulti run``,
``openmulti reproduce``, the studies, ``openmulti train`` and ``parallel_env`` alike. Each preset is the default
tree (``Experiment()``, which is ``fast``) with the changes below; every entry point starts from one and applies
its overrides, so a name means the same episode everywhere (scene presets such as ``room0`` are another thing,
in ``openmulti_env.world.presets``).

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
(docs/schedules.md); ``rl_lite`` is 12 steps as well with 40 % fewer frames (so shorter tours: the planner takes
at most a third of the frames as key views, 12 against 20, about 30 % less path), one iteration per keyframe,
half the rays and a quarter of the refit steps (issue 47: about 1.5x the env steps an hour; whether it ranks
schedules as ``fast`` does is docs/transfer.md); ``rl_tiny`` (a tenth of a second a step) is for tests.
"""

from __future__ import annotations

from dataclasses import replace
from types import MappingProxyType
from typing import Any, Mapping

from mapping.model.agent_config import MappingConfig
from mapping.team import TeamConfig
from openmulti_env.experiment.overrides import apply_overrides
from openmulti_env.experiment.tree import DEFAULT_PRESETS, Experiment
from openmulti_env.world.world import WorldConfig

RL_SIZED = {"world.sensor.width": 80, "world.sensor.height": 60, "perception.text_encoder": "minilm",
            "team.consistency.iterations": 1, "env.map_size": 48}
"""What the RL-sized presets share: small images, the MiniLM encoder, one consistency iteration, 48-pixel maps."""

PRESET_CHANGES: Mapping[str, Mapping[str, Any]] = MappingProxyType({
    "tiny": {"world.path.frames_per_agent": 24, "world.path.planning_points": 2000, "world.sensor.width": 160,
             "world.sensor.height": 120, "world.culling_edge_m": 0.1, "team.mapping.keyframe_every": 4,
             "team.mapping.iterations_per_keyframe": 10, "team.mapping.rays_per_object": 60,
             "team.mapping.rays_per_structure": 120, "team.mapping.object_voxel_m": 0.02,
             "team.mapping.structure_voxel_m": 0.04, "team.mapping.refit_steps": 20, "team.consistency.iterations": 2,
             "team.consistency.rays_per_pose": 64, "team.frames_per_round": 4},
    "demo": {"team.mapping.keyframe_every": 10, "team.mapping.object_voxel_m": 0.02,
             "team.mapping.structure_voxel_m": 0.03, "team.frames_per_round": 10},
    "fast": {},
    "full": {"world.path.frames_per_agent": 200, "team.mapping.keyframe_every": 2, "team.frames_per_round": 10,
             "env.probe_points": 10000, "env.map_size": 96},
    "rl_tiny": {**RL_SIZED, "scene": "tiny", "world.num_agents": 2, "world.path.frames_per_agent": 16,
                "world.path.planning_points": 1500, "world.culling_edge_m": 0.1, "team.mapping.keyframe_every": 2,
                "team.mapping.iterations_per_keyframe": 1, "team.mapping.rays_per_object": 24,
                "team.mapping.rays_per_structure": 48, "team.mapping.refit_steps": 10,
                "team.consistency.rays_per_pose": 24, "team.frames_per_round": 2, "env.probe_points": 600},
    "rl_small": {**RL_SIZED, "world.path.frames_per_agent": 60, "team.mapping.iterations_per_keyframe": 3,
                 "team.mapping.rays_per_object": 48, "team.mapping.rays_per_structure": 96,
                 "team.mapping.refit_steps": 20, "team.consistency.rays_per_pose": 64},
    "rl_lite": {**RL_SIZED, "world.path.frames_per_agent": 36, "team.mapping.keyframe_every": 3,
                "team.mapping.iterations_per_keyframe": 1, "team.mapping.rays_per_object": 24,
                "team.mapping.rays_per_structure": 48, "team.mapping.refit_steps": 5,
                "team.consistency.rays_per_pose": 32, "team.frames_per_round": 3},
    "rl": {**RL_SIZED, "world.sensor.width": 160, "world.sensor.height": 120,
           "team.mapping.iterations_per_keyframe": 3, "team.mapping.rays_per_object": 48,
           "team.mapping.rays_per_structure": 96, "team.mapping.refit_steps": 20, "team.consistency.rays_per_pose": 64,
           "env.map_size": 64},
})
"""Each preset as the settings it changes from ``Experiment()`` (dotted paths of the tree)."""


def preset_tree(name: str, changes: Mapping[str, Any]) -> Experiment:
    """The default tree with ``changes``, named ``name``, its team minimums following its path and mapping."""
    return apply_overrides(replace(Experiment(), preset=name), changes).with_team_minimums()


PRESETS: Mapping[str, Experiment] = MappingProxyType({name: preset_tree(name, changes)
                                                      for name, changes in PRESET_CHANGES.items()})
PRESET_NAMES = tuple(PRESETS)
PRESET_SUMMARIES: Mapping[str, str] = MappingProxyType({
    "tiny": "smoke runs and tests: 24 frames per agent at 160x120",
    "demo": "make demo: fast's paths, a keyframe every 10th frame, 2 cm / 3 cm meshes",
    "fast": "the measured setting: 120 frames per agent, a keyframe every 5th, 20 iterations each",
    "full": "the paper's setting: 200 frames per agent, a keyframe every 2nd",
    "rl_tiny": "RL tests: 2 agents in the tiny room, 16 frames at 80x60, 1 iteration per keyframe",
    "rl_small": "RL training: 60 frames per agent at 80x60 (12 steps), where schedules end points apart",
    "rl_lite": "cheaper training: 12 steps of 36 frames (shorter tours), 1 iteration per keyframe, half the rays",
    "rl": "RL-sized: room0, 120 frames at 160x120, 3 iterations per keyframe, about a second per step",
})
"""One line per preset for ``--help`` and the docs."""


def get_preset(name: str) -> Experiment:
    """The preset called ``name`` (ValueError naming the known ones)."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {PRESET_NAMES}")
    return PRESETS[name]


def default_preset(entry_point: str) -> Experiment:
    """The preset an entry point starts from when none is given (``DEFAULT_PRESETS``)."""
    return get_preset(DEFAULT_PRESETS[entry_point])


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
