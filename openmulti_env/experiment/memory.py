"""What the largest allocations of a run or an env would take, estimated from the tree alone before anything is
built, and the check that refuses a tree any one of them would not fit (``check_memory``).

Each field has a range of its own (``mapping.config_fields``); these estimates cover what grows with a product of
several fields (frames x image size, map_size^2 x levels, ...), where values each in range still multiply past the
machine. What depends on the scene (its viewpoints, faces and instances) is estimated for ``NOMINAL_ROOM_M``, the
size of the presets' largest rooms: a scene twice as large takes about twice as much."""

from __future__ import annotations

import os
from dataclasses import dataclass

from openmulti_env.experiment.options import value_at
from openmulti_env.experiment.tree import Experiment
from openmulti_env.world.world import SINGLE_AGENT_REGIONS

MEMORY_SHARE = 0.25
"""Share of the machine's physical memory one allocation of a run or an env may take (the estimate of each one
below must stay under it): the rest is the process's others, the OS's and other jobs'."""
FALLBACK_MEMORY_BYTES = 8 * 2**30
"""Physical memory assumed where ``os.sysconf`` cannot say (not POSIX)."""
GIB = 2**30
NOMINAL_ROOM_M = (7.0, 6.0, 3.0)
"""The room the scene-dependent estimates assume (the presets' rooms are 3-7 m across and under 3 m high)."""
NOMINAL_SURFACE_M2 = 250.0
"""Surface of such a room with its furniture, before culling subdivides it."""
NOMINAL_INSTANCES = 64
"""Instances one agent's map holds in such a room (their networks train side by side)."""
POSE_BYTES = 4 * 4 * 8 * 3
"""A camera pose (a 4 x 4 float64) and the two copies the planner makes of a path."""
RENDER_BYTES_PER_PIXEL = 32
"""A rendered frame: the GL targets of its colour and segmentation passes (RGBA + depth each, 16 bytes), its RGB,
depth and instance images (11) and the depth noise's scratch."""
KEYFRAME_BYTES_PER_PIXEL = 7
"""A keyframe pixel held by the mapper: uint8 RGB and float32 depth."""
PROBE_BYTES = 6 * 8 + 4
"""A probe point: float64 position and normal, its instance id (and a covered flag per agent on top)."""
LEVEL_STEP_M = 0.05
"""Height of a level of the top-down map's columns (``TopDownGrid.column_grid``)."""
QUERY_BYTES_PER_VOXEL = 64
"""A voxel of the top-down map's query: its float64 centre, index and ravelled index, float32 occupancy and flag."""
MESH_BYTES_PER_VOXEL = 16
"""A voxel of a mesh's occupancy grid: float32 coordinates and occupancy."""
CANDIDATE_BYTES = 10
"""A (key-view candidate, planning point) pair: two float32 cover matrices and two boolean rows."""
ACTIVATION_BYTES = 4 * 8
"""A float32 activation of an instance network, kept through its layers and for the backward pass."""
OBJECT_WIDTH = 32
"""Hidden width of object networks (``mapping.model.field.OBJECT_FIELD``)."""


@dataclass(frozen=True)
class Estimate:
    """One allocation: what it is, the settings it grows with, and its estimated size in bytes."""

    what: str
    fields: tuple[str, ...]
    bytes: float


def physical_memory_bytes() -> int:
    """This machine's physical memory (``FALLBACK_MEMORY_BYTES`` where the OS cannot say)."""
    try:
        pages, size = os.sysconf("SC_PHYS_PAGES"), os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return FALLBACK_MEMORY_BYTES
    return pages * size if pages > 0 and size > 0 else FALLBACK_MEMORY_BYTES


def memory_budget_bytes() -> float:
    """What one allocation may take here: ``MEMORY_SHARE`` of the physical memory."""
    return MEMORY_SHARE * physical_memory_bytes()


def nominal_viewpoints(tree: Experiment) -> float:
    """Free-space viewpoints of ``NOMINAL_ROOM_M`` at the tree's grid step and heights."""
    free = tree.world.free_space
    across = [max(side - 2 * free.clearance_m, 0.0) / free.spacing_m + 1 for side in NOMINAL_ROOM_M[:2]]
    return across[0] * across[1] * len(free.heights_m)


def world_estimates(tree: Experiment) -> list[Estimate]:
    """The simulated world's allocations (none for a data set: its images and frames are its own)."""
    if tree.data.path is not None:
        return []
    world, path = tree.world, tree.world.path
    paths = max(world.num_agents, SINGLE_AGENT_REGIONS if world.num_agents == 1 else 0)
    pixels = world.sensor.width * world.sensor.height
    viewpoints = nominal_viewpoints(tree)
    faces = 2 * NOMINAL_SURFACE_M2 / world.culling_edge_m ** 2
    candidates = viewpoints / paths * path.yaw_steps * len(path.pitches_deg)
    team = tree.team.mapping
    return [
        Estimate("the agents' camera paths", ("world.num_agents", "world.path.frames_per_agent"),
                 paths * path.frames_per_agent * POSE_BYTES),
        Estimate("one rendered frame", ("world.sensor.width", "world.sensor.height"), pixels * RENDER_BYTES_PER_PIXEL),
        Estimate("the team's keyframe buffers", ("world.num_agents", "team.mapping.keyframe_capacity",
                                                  "world.sensor.width", "world.sensor.height"),
                 world.num_agents * team.keyframe_capacity * pixels * KEYFRAME_BYTES_PER_PIXEL),
        Estimate("the culling's visibility of every face from every viewpoint",
                 ("world.culling_edge_m", "world.free_space.spacing_m", "world.free_space.heights_m"), viewpoints * faces),
        Estimate("the planner's key-view candidates", ("world.path.planning_points", "world.path.yaw_steps",
                                                        "world.path.pitches_deg", "world.free_space.spacing_m"),
                 candidates * path.planning_points * CANDIDATE_BYTES),
    ]


def env_estimates(tree: Experiment) -> list[Estimate]:
    """The env's (and a run's observer's) allocations."""
    env = tree.env
    levels = NOMINAL_ROOM_M[2] / LEVEL_STEP_M
    return [
        Estimate("the probe points", ("env.probe_points", "world.num_agents"),
                 env.probe_points * (PROBE_BYTES + tree.world.num_agents)),
        Estimate("the top-down map's query", ("env.map_size",), env.map_size ** 2 * levels * QUERY_BYTES_PER_VOXEL),
        Estimate("the env's frame cache", ("env.frame_cache_mb",), env.frame_cache_mb * 1e6),
    ]


def mapper_estimates(tree: Experiment) -> list[Estimate]:
    """One agent's mapper: a training step's samples over its instances, and a mesh's grid."""
    mapping = tree.team.mapping
    samples = mapping.sampler.n_stratified + mapping.sampler.n_surface
    rays = max(mapping.rays_per_object, mapping.rays_per_structure)
    width = max(mapping.structure_width, OBJECT_WIDTH, tree.global_map.width if tree.team.global_map else 0)
    out = [
        Estimate("one training step's samples", ("team.mapping.rays_per_object", "team.mapping.rays_per_structure",
                                                  "team.mapping.sampler", "team.mapping.structure_width"),
                 rays * samples * width * ACTIVATION_BYTES * NOMINAL_INSTANCES),
        Estimate("a mesh's occupancy grid", ("team.mapping.max_mesh_resolution",),
                 mapping.max_mesh_resolution ** 3 * MESH_BYTES_PER_VOXEL),
    ]
    if tree.team.global_map:
        sdf = tree.global_map.sdf
        out.append(Estimate("the scene SDF's training step", ("global_map.sdf.rays", "global_map.sdf.n_stratified",
                                                               "global_map.sdf.n_surface", "global_map.sdf.width"),
                            sdf.rays * (sdf.n_stratified + sdf.n_surface) * sdf.width * ACTIVATION_BYTES))
    return out


def estimates(tree: Experiment) -> list[Estimate]:
    """Every allocation estimated for ``tree``."""
    return world_estimates(tree) + env_estimates(tree) + mapper_estimates(tree)


def memory_problem(tree: Experiment, budget: float | None = None) -> str | None:
    """Why one of ``tree``'s allocations would not fit in ``budget`` bytes (``memory_budget_bytes`` by default),
    naming it, its estimate in GiB and the settings it depends on with their values; None when they all fit."""
    budget = memory_budget_bytes() if budget is None else budget
    for estimate in estimates(tree):
        if estimate.bytes > budget:
            given = ", ".join(f"{p}={shown(value_at(tree, p))}" for p in estimate.fields)
            return (f"{estimate.what} would take an estimated {estimate.bytes / GIB:.1f} GiB ({given}), more than "
                    f"the {budget / GIB:.1f} GiB one allocation may take on this machine ({MEMORY_SHARE:.0%} of its "
                    f"memory, openmulti_env.experiment.memory.MEMORY_SHARE)")
    return None


def shown(value) -> str:
    """A setting as a message quotes it (a nested node as ``...``)."""
    return "..." if hasattr(value, "__dataclass_fields__") else repr(value)
