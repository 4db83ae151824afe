"""The TSDF reference of a synthetic sequence against the mesh it was rendered from."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import trimesh
from scipy.spatial import cKDTree

from mapping.data import Frame, Intrinsics
from mapping.evaluate.reference import TSDFConfig, tsdf_reference_mesh

K = Intrinsics(160, 120, 80.0, 80.0, 79.5, 59.5)


def _room() -> trimesh.Trimesh:
    """Inside of a 3 x 3 x 2.5 m room (normals inward) with a 50 x 40 x 60 cm box on the floor."""
    room = trimesh.creation.box(extents=(3.0, 3.0, 2.5))
    room.apply_translation((1.5, 1.5, 1.25))
    room.invert()
    box = trimesh.creation.box(extents=(0.5, 0.4, 0.6))
    box.apply_translation((1.5, 1.8, 0.3))
    return trimesh.util.concatenate([room, box])


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)  # OpenCV axes: x right, y down, z forward
    pose[:3, 3] = eye
    return pose


def _frames(mesh: trimesh.Trimesh, n: int) -> list[Frame]:
    """Exact depth of ``mesh`` from ``n`` cameras circling the room (open3d ray casting)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    frames = []
    for i, a in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False)):
        eye = np.array([1.5 + 0.6 * np.cos(a), 1.0 + 0.6 * np.sin(a), 1.3])
        pose = _look_at(eye, np.array([1.5 + 1.5 * np.cos(2 * a), 1.5 + 1.5 * np.sin(2 * a), 0.6]))
        rays = scene.create_rays_pinhole(o3d.core.Tensor(K.matrix), o3d.core.Tensor(np.linalg.inv(pose)), K.width, K.height)
        depth = scene.cast_rays(rays)["t_hit"].numpy()  # the rays have unit z in the camera: t = depth
        depth[~np.isfinite(depth)] = 0.0
        frames.append(Frame(np.full((K.height, K.width, 3), 128, np.uint8), depth.astype(np.float32), pose, K, index=i))
    return frames


def _observed_gt_points(frames: list[Frame]) -> np.ndarray:
    """The known surface where the cameras saw it: the exact depth back-projected."""
    return np.concatenate([f.backproject(stride=2) for f in frames])


def test_tsdf_reference_matches_the_known_mesh_within_1cm():
    mesh = _room()
    frames = _frames(mesh, 8)
    ref = tsdf_reference_mesh(frames, TSDFConfig(voxel_size_m=0.01))
    assert len(ref.faces) > 1000
    samples, _ = trimesh.sample.sample_surface(ref, 20000, seed=0)
    _, acc, _ = trimesh.proximity.closest_point(mesh, samples)  # reference -> known mesh
    seen = _observed_gt_points(frames)[::20]
    comp, _ = cKDTree(np.asarray(ref.vertices)).query(seen)  # observed known surface -> reference vertices
    assert acc.mean() < 0.01 and comp.mean() < 0.01
    assert np.percentile(acc, 95) < 0.01


def test_few_frames_still_give_a_reference_and_no_depth_gives_an_empty_one():
    frames = _frames(_room(), 2)  # below the default weight threshold of open3d (3 observations)
    assert len(tsdf_reference_mesh(frames[:1]).faces) > 0
    blank = [Frame(f.rgb, np.zeros_like(f.depth), f.pose, K) for f in frames]
    assert len(tsdf_reference_mesh(blank).faces) == 0
