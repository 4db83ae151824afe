"""What the simulated front end may know about each instance of a scene (``InstanceInfo``).

``touching`` pairs are the candidates for under-segmentation (two mugs side by side, a book on a
shelf): two non-structure instances touch when points sampled on their surfaces come within
``touch_distance_m`` of each other.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from mapping.perception.types import InstanceInfo
from openmulti_env.world.scene import Scene

SAMPLE_SPACING_M = 0.015  # surface samples about this far apart, finer than the default touch distance
MIN_SAMPLES, MAX_SAMPLES = 200, 20000  # per instance, so tiny parts are seen and big ones stay cheap


def surface_samples(mesh: trimesh.Trimesh, spacing_m: float = SAMPLE_SPACING_M, seed: int = 0) -> np.ndarray:
    """(n, 3) float64 points on ``mesh``, about ``spacing_m`` apart (area-weighted, seeded), plus its vertices."""
    count = int(np.clip(mesh.area / spacing_m**2, MIN_SAMPLES, MAX_SAMPLES))
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.vstack([np.asarray(points, np.float64), np.asarray(mesh.vertices, np.float64)])


def touching_pairs(scene: Scene, touch_distance_m: float = 0.02) -> set[tuple[int, int]]:
    """Pairs (i < j) of non-structure instance ids whose surfaces come within ``touch_distance_m``."""
    if not touch_distance_m > 0:
        raise ValueError(f"touch_distance_m must be > 0, got {touch_distance_m}")
    objects = [inst for inst in scene.instances if not inst.is_structure and len(inst.mesh.faces)]
    bounds = np.array([inst.mesh.bounds for inst in objects]).reshape(-1, 2, 3)
    samples = {inst.instance_id: surface_samples(inst.mesh, min(SAMPLE_SPACING_M, touch_distance_m))
               for inst in objects}
    trees: dict[int, cKDTree] = {}
    pairs: set[tuple[int, int]] = set()
    for a in range(len(objects)):
        for b in range(a + 1, len(objects)):
            # boxes farther apart than the touch distance cannot touch
            gap = np.maximum(bounds[a, 0] - bounds[b, 1], bounds[b, 0] - bounds[a, 1])
            if np.any(gap > touch_distance_m):
                continue
            ia, ib = objects[a].instance_id, objects[b].instance_id
            if ib not in trees:
                trees[ib] = cKDTree(samples[ib])
            dist, _ = trees[ib].query(samples[ia], k=1, distance_upper_bound=touch_distance_m)
            if np.isfinite(dist).any():
                pairs.add((min(ia, ib), max(ia, ib)))
    return pairs


def instance_infos(scene: Scene, touch_distance_m: float = 0.02) -> list[InstanceInfo]:
    """One ``InstanceInfo`` per scene instance (scene order), with ``touching`` from mesh proximity.

    Structure (walls, floor, ceiling) never touches anything here: it is never under-segmented.
    """
    neighbours: dict[int, set[int]] = {inst.instance_id: set() for inst in scene.instances}
    for i, j in touching_pairs(scene, touch_distance_m):
        neighbours[i].add(j)
        neighbours[j].add(i)
    return [InstanceInfo(inst.instance_id, inst.category, inst.caption, inst.color_name, inst.material,
                         inst.is_structure, tuple(sorted(neighbours[inst.instance_id])))
            for inst in scene.instances]


def instance_anchor_points(scene: Scene, count: int = 2000, seed: int = 0) -> dict[int, np.ndarray]:
    """Instance id -> (count, 3) float64 surface points: fixes the over-segmentation planes of
    ``mapping.perception.OracleSegmenter`` independently of the order frames are seen in."""
    return {inst.instance_id: np.asarray(trimesh.sample.sample_surface(inst.mesh, count, seed=seed)[0], np.float64)
            for inst in scene.instances if len(inst.mesh.faces)}


def category_vocabulary(world) -> list[str]:
    """``world``'s category names (what zero-shot labelling chooses from), sorted."""
    return sorted({inst.category for inst in world.scene.instances})


def semantic_ground_truth(world, n_points: int = 200_000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) points on ``world``'s observable ground-truth surface and their (n,) category names."""
    points, _, ids = world.surface.sample_points(n_points, seed=seed)
    category = {inst.instance_id: inst.category for inst in world.scene.instances}
    return points, np.array([category[int(i)] for i in ids])
