"""Run presets: how big a run is (frames, image size, mapper effort). ``full`` is the reference setting, ``fast`` the
default for quick studies, ``demo`` the paths of ``fast`` with half the keyframes and coarser meshes (``make demo``
within 5 minutes), ``tiny`` for tests and smoke runs."""

from __future__ import annotations

from dataclasses import replace

from mapping.agent import MappingConfig
from mapping.team import TeamConfig
from openmulti_env.world.paths import PathConfig
from openmulti_env.world.sensor import SensorConfig
from openmulti_env.world.world import WorldConfig

RUN_PRESETS = ("full", "fast", "demo", "tiny")


def world_config(preset: str, num_agents: int) -> WorldConfig:
    """World settings of a run preset (raises ValueError naming the known presets)."""
    if preset == "full":
        return WorldConfig(num_agents=num_agents, path=PathConfig(frames_per_agent=200))
    if preset in ("fast", "demo"):
        return WorldConfig(num_agents=num_agents, path=PathConfig(frames_per_agent=120))
    if preset == "tiny":
        base = WorldConfig(num_agents=num_agents)
        return replace(base, path=PathConfig(frames_per_agent=24, planning_points=2000),
                       sensor=SensorConfig(width=160, height=120), culling_edge_m=0.1)
    raise ValueError(f"unknown preset {preset!r}; choose one of {RUN_PRESETS}")


def mapping_config(preset: str) -> MappingConfig:
    """Mapper settings of a run preset (raises ValueError naming the known presets)."""
    if preset == "full":
        return MappingConfig(keyframe_every=2, iterations_per_keyframe=20)
    if preset == "fast":
        return MappingConfig(keyframe_every=5, iterations_per_keyframe=20)
    if preset == "demo":
        return MappingConfig(keyframe_every=10, iterations_per_keyframe=20, object_voxel_m=0.02, structure_voxel_m=0.03)
    if preset == "tiny":
        return MappingConfig(keyframe_every=4, iterations_per_keyframe=10, rays_per_object=60, rays_per_structure=120,
                             object_voxel_m=0.02, structure_voxel_m=0.04, refit_steps=20)
    raise ValueError(f"unknown preset {preset!r}; choose one of {RUN_PRESETS}")


def frames_per_round(preset: str) -> int:
    """Frames each agent reads per round: one keyframe per round on ``fast``, five on ``full``."""
    return {"full": 10, "fast": 5, "demo": 10, "tiny": 4}[_known(preset)]


def team_config(preset: str, **options) -> TeamConfig:
    """The team settings of a run preset; ``options`` replace TeamConfig fields (e.g. ``consistency``, or
    ``mapping`` for other mapper settings than the preset's;
    on ``tiny`` its iterations and rays are cut to the preset's size)."""
    mapping = options.pop("mapping", None) or mapping_config(preset)
    config = TeamConfig(mapping=mapping, frames_per_round=frames_per_round(preset), **options)
    if preset == "tiny":
        config = replace(config, consistency=replace(config.consistency, iterations=2, rays_per_pose=64))
    return config


def _known(preset: str) -> str:
    if preset not in RUN_PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {RUN_PRESETS}")
    return preset
