"""Interpenetration checks between instances, part by part.

Objects are unions of closed primitive parts, so "A does not penetrate B" is checked as: no point of
A's parts lies deeper than ``tol_m`` inside any part of B. Touching (a mug on a table) is allowed.
"""

from __future__ import annotations

import numpy as np
import trimesh

from openmulti_env.world.scene import Instance

CONTACT_TOLERANCE_M = 2e-3  # resting contact and float round-off; deeper is interpenetration


def boxes_overlap(a: np.ndarray, b: np.ndarray, margin: float = 0.0) -> bool:
    """Whether two (2, 3) axis-aligned boxes overlap by more than ``margin`` on every axis."""
    return bool(np.all(np.minimum(a[1], b[1]) - np.maximum(a[0], b[0]) > margin))


def _probe_points(part: trimesh.Trimesh, count: int) -> np.ndarray:
    pts, _ = trimesh.sample.sample_surface(part, count, seed=0)
    return np.concatenate([np.asarray(part.vertices), np.asarray(pts)])


def parts_penetrate(a: trimesh.Trimesh, b: trimesh.Trimesh, tol_m: float = CONTACT_TOLERANCE_M) -> bool:
    """True when a point of ``a`` lies more than ``tol_m`` inside ``b`` or vice versa."""
    if not boxes_overlap(a.bounds, b.bounds, tol_m):
        return False
    for x, y in ((a, b), (b, a)):
        pts = _probe_points(x, 300)
        pts = pts[np.all((pts > y.bounds[0] + tol_m) & (pts < y.bounds[1] - tol_m), axis=1)]
        if len(pts) and np.any(trimesh.proximity.signed_distance(y, pts) > tol_m):
            return True
    return False


def instances_penetrate(a: Instance, b: Instance, tol_m: float = CONTACT_TOLERANCE_M) -> bool:
    """True when any part of ``a`` penetrates any part of ``b``."""
    if not boxes_overlap(a.bounds, b.bounds, tol_m):
        return False
    return any(parts_penetrate(pa, pb, tol_m) for pa in a.parts for pb in b.parts)


def find_interpenetrations(instances: list[Instance], tol_m: float = CONTACT_TOLERANCE_M) -> list[tuple[int, int]]:
    """All pairs of instance ids whose parts interpenetrate (deeper than ``tol_m``)."""
    hits = []
    for i, a in enumerate(instances):
        for b in instances[i + 1 :]:
            if instances_penetrate(a, b, tol_m):
                hits.append((a.instance_id, b.instance_id))
    return hits
