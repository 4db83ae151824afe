"""Coverage: the share of the observable ground truth that an agent's frames have seen.

A ground-truth point counts as covered when it lies within ``radius_m`` (5 cm, the completion-ratio
threshold) of a back-projected depth point of some frame. Depth comes from exact ray casting, which
equals the sensor's depth, so coverage needs no GL context.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from mapping.data import Intrinsics, backproject_depth
from mapping.evaluate.raycast import MeshRaycaster

COVERAGE_RADIUS_M = 0.05


def observed_points(caster: MeshRaycaster, poses: np.ndarray, intrinsics: Intrinsics, stride: int = 2,
                    max_depth_m: float = 10.0, voxel_m: float = 0.01) -> np.ndarray:
    """Back-projected depth points of all ``poses``, voxel-downsampled to ``voxel_m``.

    Returns
    -------
    points : (n, 3) float
    """
    chunks = []
    for pose in poses:
        depth, _ = caster.render_depth(pose, intrinsics, stride=stride)
        depth[depth > max_depth_m] = 0.0
        strided = Intrinsics(depth.shape[1], depth.shape[0], intrinsics.fx / stride, intrinsics.fy / stride,
                             intrinsics.cx / stride, intrinsics.cy / stride)
        chunks.append(backproject_depth(depth, strided, pose))
    pts = np.concatenate(chunks) if chunks else np.zeros((0, 3))
    if len(pts) == 0:
        return pts
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    return np.asarray(pcd.voxel_down_sample(voxel_m).points)


def covered_mask(gt_points: np.ndarray, seen_points: np.ndarray, radius_m: float = COVERAGE_RADIUS_M) -> np.ndarray:
    """(n,) bool: which ground-truth points have a seen point within ``radius_m``."""
    if len(seen_points) == 0:
        return np.zeros(len(gt_points), dtype=bool)
    dist, _ = cKDTree(seen_points).query(gt_points, distance_upper_bound=radius_m)
    return np.isfinite(dist)


@dataclass
class CoverageReport:
    """Per-agent and union coverage of the observable surface, in [0, 1]."""

    per_agent: list[float]
    union: float
    pairwise_overlap: list[list[float]]
    """Share of the surface covered by both agent i and agent j."""

    def as_dict(self) -> dict:
        """JSON-ready, percentages rounded to 0.1."""
        return {
            "per_agent_pct": [round(100 * c, 1) for c in self.per_agent],
            "union_pct": round(100 * self.union, 1),
            "pairwise_overlap_pct": [[round(100 * c, 1) for c in row] for row in self.pairwise_overlap],
        }


def coverage_report(caster: MeshRaycaster, gt_points: np.ndarray, agent_poses: list[np.ndarray],
                    intrinsics: Intrinsics, stride: int = 2) -> CoverageReport:
    """Coverage of ``gt_points`` (samples of the observable surface) by each agent's frames."""
    masks = [covered_mask(gt_points, observed_points(caster, poses, intrinsics, stride)) for poses in agent_poses]
    union = np.any(masks, axis=0)
    overlap = [[float(np.mean(a & b)) for b in masks] for a in masks]
    return CoverageReport([float(m.mean()) for m in masks], float(union.mean()), overlap)
