"""Which surface points a set of viewpoints can see, and culling a mesh to it: for any mesh, simulated
or real (the observable ground truth of the simulator is built from the same test).

A reconstruction is scored on what free space can see of it, as published evaluations cull meshes to
observed space (``cull_to_viewpoints``).
"""

from __future__ import annotations

import numpy as np
import trimesh

from mapping.evaluate.raycast import MeshRaycaster

# Tolerances, each with its reason:
SURFACE_OFFSET_M = 2e-3  # lift a face's test point off the face so the ray does not hit the face itself
OCCLUSION_SLACK_M = 1e-3  # a hit this much before the target still counts as reaching it (float32 rays)
FACING_MARGIN = 1e-9  # the expanded facing product may round 1e-14 away from the exact one: never rule out on it
RANGE_MARGIN_M = 1e-6  # likewise for the expanded squared distance


def visibility_matrix(caster: MeshRaycaster, viewpoints: np.ndarray, points: np.ndarray, normals: np.ndarray,
                      max_range_m: float = 8.0, stop_when_seen: bool = False, block: int = 8) -> np.ndarray:
    """Which viewpoints see which surface points.

    A point is seen from a viewpoint when the viewpoint is on the point's front side (``normals``),
    within ``max_range_m``, and the segment between them hits nothing first.

    Speed, with the same answer as testing every point from every viewpoint: for ``block`` viewpoints
    at a time, two matrix products (n . p - n . e and |p|^2 - 2 p . e + |e|^2) rule out the points
    that face away or lie out of range, with a margin far above their rounding error; the exact test
    (and the ray) then runs only on the rest, computed as it always was, so every ray and every
    comparison is bit-identical. Measured on a 1.2 M-face map against 270 viewpoints: the arithmetic
    around the rays took 0.4x the time (``docs/profile.md``).

    Parameters
    ----------
    viewpoints : (m, 3) float
    points, normals : (n, 3) float
    stop_when_seen : bool
      Skip points already seen by an earlier viewpoint (enough for culling, much faster); the
      matrix then holds only the first viewpoint that saw each point.
    block : int
      Viewpoints ruled on together by the matrix products (memory: 2 x 8 bytes x n x block).

    Returns
    -------
    visible : (m, n) bool
    """
    viewpoints = np.asarray(viewpoints, np.float64).reshape(-1, 3)
    points, normals = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    lifted = points + SURFACE_OFFSET_M * normals
    facing_offset = np.einsum("ij,ij->i", normals, lifted)  # n . p
    squared = np.einsum("ij,ij->i", lifted, lifted)  # |p|^2
    reach = (max_range_m + RANGE_MARGIN_M) ** 2
    out = np.zeros((len(viewpoints), len(points)), dtype=bool)
    todo = np.arange(len(points))
    for start in range(0, len(viewpoints), max(1, block)):
        eyes = viewpoints[start:start + max(1, block)]
        lifted_todo, normals_todo = lifted[todo], normals[todo]
        # the expanded forms, one product each: a superset of the exact test's candidates
        maybe = (facing_offset[todo, None] - normals_todo @ eyes.T < FACING_MARGIN) & (
            squared[todo, None] - 2.0 * (lifted_todo @ eyes.T) + np.einsum("ij,ij->i", eyes, eyes) < reach)
        seen = np.zeros(len(todo), dtype=bool)
        for j, eye in enumerate(eyes):
            column = maybe[:, j] & ~seen if stop_when_seen else maybe[:, j]
            sub = np.flatnonzero(column)
            if len(sub) == 0:
                continue
            to_pt = lifted_todo[sub] - eye
            dist = np.linalg.norm(to_pt, axis=1)
            candidate = ((normals_todo[sub] * to_pt).sum(axis=1) < 0) & (dist < max_range_m) & (dist > 1e-6)
            idx = np.flatnonzero(candidate)
            if len(idx) == 0:
                continue
            t, _ = caster.cast(eye, to_pt[idx] / dist[idx, None])
            hit = sub[idx[t >= dist[idx] - OCCLUSION_SLACK_M]]
            out[start + j, todo[hit]] = True
            seen[hit] = True
        if stop_when_seen:
            todo = todo[~seen]
    return out


def group_keys(cells: np.ndarray, side: np.ndarray) -> np.ndarray:
    """One int64 per (voxel (n, 3), side (n,) in 0..5), ordered as the rows (x, y, z, side) sort: the
    groups of ``np.unique(rows, axis=0)``, numbered alike, at a fraction of its time (a 1-D sort)."""
    cells = cells - cells.min(axis=0)
    span = cells.max(axis=0) + 1
    if float(np.prod(span.astype(np.float64))) * 6 >= 2.0**62:
        _, inverse = np.unique(np.concatenate([cells, side[:, None]], axis=1), axis=0, return_inverse=True)
        return inverse.reshape(-1)
    return ((cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]) * 6 + side


def cull_to_viewpoints(mesh: trimesh.Trimesh, viewpoints: np.ndarray, max_range_m: float = 8.0,
                       group_m: float | None = 0.02) -> trimesh.Trimesh:
    """Keep the faces of ``mesh`` that the ``viewpoints`` can see, occlusion by ``mesh`` itself included.

    The reconstruction gets the same treatment as the ground truth (``compute_observable_surface``):
    surfaces that no camera in free space could ever see (the closed back of a wall's field box,
    occupancy hallucinated inside furniture) are not scored, as published evaluations cull meshes to
    observed space.

    Speed: faces are grouped by ``group_m`` voxel of their centre and by the axis and sign of their
    normal's largest component (so the two sides of a thin wall never share a group); one ray per
    group (its mean centre and normal) decides for all its faces. A marching-cubes mesh at 1 cm has
    ~10 faces per 2 cm group: a 3.4 M-face team map took 85 s face by face, about a tenth of it grouped;
    ``make demo``'s 2-3 cm meshes have 1.6 faces per group (1.24 M faces, 0.77 M groups: 41 M rays
    against 270 viewpoints, about 9 s of a 13 s culling here).
    ``group_m=None`` tests every face.
    """
    if len(mesh.faces) == 0:
        return mesh
    caster = MeshRaycaster(mesh)
    order = np.random.default_rng(0).permutation(len(viewpoints))
    centres, normals = np.asarray(mesh.triangles_center), np.asarray(mesh.face_normals)
    if group_m:
        axis = np.abs(normals).argmax(axis=1)
        sign = np.take_along_axis(normals, axis[:, None], 1)[:, 0] > 0
        _, group, counts = np.unique(group_keys(np.floor(centres / group_m).astype(np.int64), axis * 2 + sign),
                                     return_inverse=True, return_counts=True)
        group = group.reshape(-1)
        mean_centre = np.stack([np.bincount(group, centres[:, k]) for k in range(3)], 1) / counts[:, None]
        mean_normal = np.stack([np.bincount(group, normals[:, k]) for k in range(3)], 1)
        mean_normal /= np.maximum(np.linalg.norm(mean_normal, axis=1, keepdims=True), 1e-12)
        vis = visibility_matrix(caster, np.asarray(viewpoints)[order], mean_centre, mean_normal, max_range_m,
                                stop_when_seen=True).any(axis=0)[group]
    else:
        vis = visibility_matrix(caster, np.asarray(viewpoints)[order], centres, normals, max_range_m,
                                stop_when_seen=True).any(axis=0)
    return mesh.submesh([np.flatnonzero(vis)], append=True, repair=False)
