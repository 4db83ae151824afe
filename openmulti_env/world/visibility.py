"""The observable ground truth: the scene's surface culled to what can be seen from free space.

Published evaluations cull Replica meshes to what cameras can see, so faces under furniture, against
walls or inside other objects do not count against a reconstruction. We do the same with a dense set
of virtual cameras over the room's free space at several heights: the mesh is first subdivided into
small triangles, and a triangle is observable when its front side has an unoccluded line of sight to
at least one virtual camera. Coverage and every geometric metric use the culled mesh.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from mapping.config_fields import bounded, lengths
from mapping.evaluate.raycast import MeshRaycaster
from mapping.evaluate.visibility import visibility_matrix
from openmulti_env.world.scene import Scene


@dataclass(frozen=True)
class FreeSpaceConfig:
    """Where the virtual cameras of the culling (and the agents' candidate viewpoints) may stand."""

    spacing_m: float = field(default=0.5, metadata=bounded(0.05, 10))
    """Grid step of the viewpoints on the floor plan."""
    heights_m: tuple[float, ...] = field(default=(0.9, 1.4, 1.9), metadata=lengths(1, 32, bounded(0, 100)))
    """Camera heights above the floor (a person's and a robot's eye heights)."""
    clearance_m: float = field(default=0.25, metadata=bounded(0, 10))
    """Minimum distance from walls and from any object's bounding box."""


def free_space_viewpoints(scene: Scene, config: FreeSpaceConfig | None = None) -> np.ndarray:
    """Camera positions over the room's free space.

    Returns
    -------
    positions : (n, 3) float
      Points on a grid over the room at ``config.heights_m``, at least ``clearance_m`` from walls,
      floor, ceiling and from every object's axis-aligned bounding box.
    """
    cfg = config or FreeSpaceConfig()
    sx, sy, sz = scene.size_m
    c = cfg.clearance_m
    xs = _grid_axis(c, sx - c, cfg.spacing_m)
    ys = _grid_axis(c, sy - c, cfg.spacing_m)
    zs = np.array([h for h in cfg.heights_m if c <= h <= sz - c])
    if len(xs) == 0 or len(ys) == 0 or len(zs) == 0:
        raise ValueError(f"scene {scene.name!r} ({sx:.2f}x{sy:.2f}x{sz:.2f} m) has no free space for cameras")
    grid = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)
    free = np.ones(len(grid), dtype=bool)
    for inst in scene.instances:
        if inst.is_structure:
            continue
        lo, hi = inst.bounds[0] - c, inst.bounds[1] + c
        free &= ~np.all((grid >= lo) & (grid <= hi), axis=1)
    if not free.any():
        raise ValueError(f"scene {scene.name!r}: furniture leaves no free space for cameras")
    return grid[free]


def _grid_axis(lo: float, hi: float, step: float) -> np.ndarray:
    if hi < lo:
        return np.zeros(0)
    n = int(np.floor((hi - lo) / step)) + 1
    return lo + (hi - lo - (n - 1) * step) / 2 + step * np.arange(n)


@dataclass
class ObservableSurface:
    """The scene mesh subdivided into small faces, with which faces free space can see.

    Attributes:
        mesh: the subdivided scene mesh (all faces, observable or not).
        face_instance_ids: (n_faces,) instance id of each face.
        visible: (n_faces,) True where some viewpoint sees the face's front side.
        viewpoints: (m, 3) the virtual camera positions used.
    """

    mesh: trimesh.Trimesh
    face_instance_ids: np.ndarray
    visible: np.ndarray
    viewpoints: np.ndarray

    def culled_mesh(self) -> trimesh.Trimesh:
        """Only the observable faces (face colours kept); ``culled_face_instance_ids`` labels them."""
        return self.mesh.submesh([np.flatnonzero(self.visible)], append=True, repair=False)

    @property
    def culled_face_instance_ids(self) -> np.ndarray:
        """(n_visible,) instance id of each face of ``culled_mesh()``."""
        return self.face_instance_ids[self.visible]

    @property
    def visible_fraction(self) -> float:
        """Share of the total surface area that is observable."""
        area = self.mesh.area_faces
        return float(area[self.visible].sum() / area.sum())

    def sample_points(self, count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Area-uniform points on the observable surface.

        Returns
        -------
        points : (count, 3) float
        normals : (count, 3) float
        instance_ids : (count,) int32
        """
        culled = self.culled_mesh()
        points, face = trimesh.sample.sample_surface(culled, count, seed=seed)
        normals = np.asarray(culled.face_normals)[face]
        return np.asarray(points), normals, self.culled_face_instance_ids[face].astype(np.int32)


def subdivide_scene(scene: Scene, max_edge_m: float) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Scene mesh with every edge at most ``max_edge_m``, and the instance id of each new face.

    The outer sides of walls, floor and ceiling (outside the room box) can never be seen from inside;
    they are dropped before subdividing, which would otherwise spend most faces on them.
    """
    meshes, labels = [], []
    room_lo, room_hi = np.zeros(3) - 1e-3, np.asarray(scene.size_m) + 1e-3
    for inst in scene.instances:
        m = inst.mesh
        keep = np.arange(len(m.faces))
        if inst.is_structure:
            c = np.asarray(m.triangles_center)
            keep = np.flatnonzero(np.all((c >= room_lo) & (c <= room_hi), axis=1))
        colors = np.asarray(m.visual.face_colors)[keep]
        v, f, idx = trimesh.remesh.subdivide_to_size(
            m.vertices, m.faces[keep], max_edge=max_edge_m, max_iter=12, return_index=True
        )
        sub = trimesh.Trimesh(v, f, face_colors=colors[idx], process=False)
        meshes.append(sub)
        labels.append(np.full(len(f), inst.instance_id, dtype=np.int32))
    return trimesh.util.concatenate(meshes), np.concatenate(labels)


def compute_observable_surface(
    scene: Scene,
    viewpoints: np.ndarray | None = None,
    max_edge_m: float = 0.05,
    max_range_m: float = 8.0,
    caster: MeshRaycaster | None = None,
) -> ObservableSurface:
    """Cull the scene's surface to what the ``viewpoints`` (default: free-space grid) can see: a face
    is observable when its (lifted) centre is seen from at least one viewpoint."""
    if viewpoints is None:
        viewpoints = free_space_viewpoints(scene)
    mesh, face_ids = subdivide_scene(scene, max_edge_m)
    caster = caster or MeshRaycaster(scene.mesh())
    # a spread-out order sees most faces within the first few viewpoints, so early stopping pays
    order = np.random.default_rng(0).permutation(len(viewpoints))
    vis = visibility_matrix(caster, np.asarray(viewpoints)[order], np.asarray(mesh.triangles_center),
                            np.asarray(mesh.face_normals), max_range_m, stop_when_seen=True)
    return ObservableSurface(mesh, face_ids, vis.any(axis=0), np.asarray(viewpoints))
