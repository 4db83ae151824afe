"""Run presets: how big a run is (frames, image size). ``full`` is the reference setting, ``fast`` the
default for quick studies, ``tiny`` for tests and smoke runs."""

from __future__ import annotations

from dataclasses import replace

from openmulti_env.world.paths import PathConfig
from openmulti_env.world.sensor import SensorConfig
from openmulti_env.world.world import WorldConfig

RUN_PRESETS = ("full", "fast", "tiny")


def world_config(preset: str, num_agents: int) -> WorldConfig:
    """World settings of a run preset (raises ValueError naming the known presets)."""
    if preset == "full":
        return WorldConfig(num_agents=num_agents, path=PathConfig(frames_per_agent=200))
    if preset == "fast":
        return WorldConfig(num_agents=num_agents, path=PathConfig(frames_per_agent=120))
    if preset == "tiny":
        base = WorldConfig(num_agents=num_agents)
        return replace(base, path=PathConfig(frames_per_agent=24, planning_points=2000),
                       sensor=SensorConfig(width=160, height=120), culling_edge_m=0.1)
    raise ValueError(f"unknown preset {preset!r}; choose one of {RUN_PRESETS}")
