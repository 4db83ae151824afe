"""Culling a reconstruction to what the cameras observed: the NICE-SLAM protocol.

Accuracy depends on what of a reconstruction is scored (a closed field box has a back side no camera
ever saw; occupancy hallucinated inside furniture is not surface). Published evaluations (NICE-SLAM,
and after it vMAP and MACIM on Replica) remove the faces that lie outside every camera frustum of the
sequence, or behind the depth the camera observed there, before they sample the mesh. This module is
that protocol, on plain arrays, so that it runs on any data set (``openmulti_env.world.visibility``
holds the free-space culling of the simulated world).
"""

from __future__ import annotations

import numpy as np
import trimesh

from mapping.data.frame import Intrinsics

DEPTH_SLACK_M = 0.05
"""A face up to this far behind the observed depth still counts as observed: the reconstruction's
surface sits within the completion-ratio threshold (5 cm) of the true one, so it is not "behind" it."""
NEAR_M = 0.01
"""Faces closer to a camera than this are not in its frustum (behind or at the optical centre)."""


def observed_by_cameras(points: np.ndarray, poses: np.ndarray, intrinsics: Intrinsics,
                        depths: np.ndarray | None = None, depth_slack_m: float = DEPTH_SLACK_M) -> np.ndarray:
    """Which points some camera observed: inside its frustum and not behind its observed depth.

    Parameters
    ----------
    points : (n, 3) float
      World points (e.g. face centres).
    poses : (k, 4, 4) float
      Camera-to-world poses (OpenCV axes: z forward, y down).
    intrinsics : the cameras' pinhole model (width, height give the frustum).
    depths : (k, H, W) float or None
      Observed metric depth per camera (0 = missing: no occluder known there); None tests the
      frustums only (NICE-SLAM's original culling).

    Returns
    -------
    observed : (n,) bool
    """
    pts = np.asarray(points, np.float64)
    seen = np.zeros(len(pts), bool)
    w, h = intrinsics.width, intrinsics.height
    for k, pose in enumerate(np.asarray(poses, np.float64)):
        todo = np.flatnonzero(~seen)
        if len(todo) == 0:
            break
        world_to_cam = np.linalg.inv(pose)
        cam = pts[todo] @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
        z = cam[:, 2]
        front = z > NEAR_M
        u = np.full(len(todo), -1.0)
        v = np.full(len(todo), -1.0)
        u[front] = intrinsics.fx * cam[front, 0] / z[front] + intrinsics.cx
        v[front] = intrinsics.fy * cam[front, 1] / z[front] + intrinsics.cy
        inside = front & (u >= -0.5) & (u < w - 0.5) & (v >= -0.5) & (v < h - 0.5)  # pixel (u, v) sees point (u, v)
        if depths is not None:
            idx = np.flatnonzero(inside)
            d = depths[k][np.rint(v[idx]).astype(int), np.rint(u[idx]).astype(int)]
            behind = (d > 0) & (z[idx] > d + depth_slack_m)
            inside[idx[behind]] = False
        seen[todo[inside]] = True
    return seen


def cull_to_frustums(mesh: trimesh.Trimesh, poses: np.ndarray, intrinsics: Intrinsics,
                     depths: np.ndarray | None = None, depth_slack_m: float = DEPTH_SLACK_M) -> trimesh.Trimesh:
    """The faces of ``mesh`` whose centre some camera observed (``observed_by_cameras``); the rest removed."""
    if len(mesh.faces) == 0:
        return mesh
    keep = observed_by_cameras(np.asarray(mesh.triangles_center), poses, intrinsics, depths, depth_slack_m)
    return mesh.submesh([np.flatnonzero(keep)], append=True, repair=False) if keep.any() else trimesh.Trimesh()
