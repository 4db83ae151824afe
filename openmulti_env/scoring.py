"""Scoring one map three ways, since accuracy depends on how the reconstruction is culled.

- ``free_space`` (the run's default): faces that the free-space viewpoints can see, with the
  reconstruction's own occlusion (``world.visibility.cull_to_viewpoints``);
- ``nice_slam``: faces inside some camera frustum of the agents' own poses and not behind the depth
  that camera observed (``mapping.evaluate.culling``; NICE-SLAM's protocol, used by vMAP and MACIM);
- ``unculled``: the whole reconstruction.

The ground truth is the observable surface in all three, so completion changes only by what culling
removes from the reconstruction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from mapping.data.frame import Intrinsics
from mapping.evaluate import evaluate_mesh
from mapping.evaluate.culling import cull_to_frustums
from openmulti_env.results import finite_or_none
from openmulti_env.world import World
from openmulti_env.world.visibility import cull_to_viewpoints

CULLINGS = ("free_space", "nice_slam", "unculled")
SUFFIX = {"free_space": "", "nice_slam": "_nice", "unculled": "_unculled"}
"""Metric keys per culling: ``acc_cm`` (free space), ``acc_cm_nice``, ``acc_cm_unculled``; same for comp."""


@dataclass
class CameraViews:
    """The cameras of the NICE-SLAM culling: (k, 4, 4) poses, (k, H, W) observed depths, intrinsics."""

    poses: np.ndarray
    depths: np.ndarray
    intrinsics: Intrinsics


def agents_camera_views(world: World, stride: int) -> CameraViews:
    """Every ``stride``-th pose of every agent's path with the depth the sensor observed there (the
    poses the agents took: the sequence NICE-SLAM culls with)."""
    poses, depths = [], []
    for agent, path in enumerate(world.agent_poses):
        for i in range(0, len(path), max(1, stride)):
            poses.append(np.asarray(path[i], np.float64))
            depths.append(world.render(agent, i).depth)
    return CameraViews(np.stack(poses), np.stack(depths), world.intrinsics)


def score_three_ways(mesh: trimesh.Trimesh | None, gt: trimesh.Trimesh, viewpoints: np.ndarray,
                     views: CameraViews | None, seed: int) -> dict[str, float | None]:
    """acc / comp / comp ratio of ``mesh`` under each culling (``views=None`` skips ``nice_slam``)."""
    has = mesh is not None and len(mesh.faces) > 0
    meshes = {"free_space": cull_to_viewpoints(mesh, viewpoints) if has else None,
              "unculled": mesh if has else None}
    if views is not None:
        meshes["nice_slam"] = cull_to_frustums(mesh, views.poses, views.intrinsics, views.depths) if has else None
    out: dict[str, float | None] = {}
    for name, culled in meshes.items():
        m = evaluate_mesh(culled if culled is not None and len(culled.faces) else None, gt, seed=seed)
        s = SUFFIX[name]
        out.update({f"acc_cm{s}": finite_or_none(m.acc_cm), f"comp_cm{s}": finite_or_none(m.comp_cm),
                    f"comp_ratio{s}": float(m.comp_ratio)})
    return out
