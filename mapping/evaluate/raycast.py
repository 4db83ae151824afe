"""Exact ray casting against a scene's ground-truth mesh (open3d), for geometry that needs no GL.

Culling, coverage and path planning cast millions of rays; open3d's RaycastingScene does that on the
CPU without a GL context. Depth from here equals the sensor's pyrender depth to float precision.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import trimesh

from mapping.data import Intrinsics


class MeshRaycaster:
    """Casts rays against one triangle mesh; ``face_ids`` maps each triangle to a label."""

    def __init__(self, mesh: trimesh.Trimesh, face_labels: np.ndarray | None = None):
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(
            o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
            o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
        )
        self.face_labels = None if face_labels is None else np.asarray(face_labels)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First hits of rays.

        Parameters
        ----------
        origins : (n, 3) float
        directions : (n, 3) float
          Not necessarily unit; ``t`` is in units of the direction's length.

        Returns
        -------
        t_hit : (n,) float32
          Ray parameter of the first hit, inf when none.
        face : (n,) int64
          Index of the hit triangle, -1 when none.
        """
        directions = np.asarray(directions)
        rays = np.empty((len(directions), 6), np.float32)  # written once in float32: no float64 copy
        rays[:, :3] = origins
        rays[:, 3:] = directions
        out = self._scene.cast_rays(o3d.core.Tensor(rays), nthreads=0)
        t = out["t_hit"].numpy()
        face = out["primitive_ids"].numpy().astype(np.int64)
        face[~np.isfinite(t)] = -1
        return t, face

    def render_depth(self, pose: np.ndarray, intrinsics: Intrinsics, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Depth image (metres along the optical axis, 0 = no hit) and per-pixel label (0 = none).

        ``pose`` is camera-to-world with OpenCV axes; pixel (u, v) looks through image point (u, v).
        With ``stride`` > 1 only every stride-th pixel is cast: the result is the image ``[::stride, ::stride]``.
        """
        k = intrinsics
        v, u = np.mgrid[0 : k.height : stride, 0 : k.width : stride]
        cam = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones(u.shape)], axis=-1).reshape(-1, 3)
        t, face = self.cast(np.asarray(pose[:3, 3]), cam @ pose[:3, :3].T)
        depth = np.where(np.isfinite(t), t, 0.0).astype(np.float32).reshape(u.shape)
        if self.face_labels is None:
            labels = (face >= 0).astype(np.int32)
        else:
            labels = np.where(face >= 0, self.face_labels[np.maximum(face, 0)], 0).astype(np.int32)
        return depth, labels.reshape(u.shape)
