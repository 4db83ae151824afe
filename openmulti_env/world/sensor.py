"""Simulated RGB-D camera: pyrender renders RGB, metric depth and an exact instance-id image.

Poses are camera-to-world in OpenCV axes (x right, y down, z forward), as in Replica/ScanNet; pyrender
wants OpenGL axes (y up, z backward), so we flip y and z before rendering.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mapping.config_fields import bounded
from mapping.data import Frame, Intrinsics
from openmulti_env.world.gl import load_pyrender
from openmulti_env.world.scene import Scene

OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])
# Replica's camera is 1200x680 with fx = fy = 600: a 90 degree horizontal field of view.
REPLICA_HFOV_DEG = 90.0
MAX_IMAGE_SIDE = 8192
"""Widest and tallest image rendered: the smallest largest render target common GL drivers offer (Mesa's
llvmpipe and most GPUs allow 16384)."""


@dataclass(frozen=True)
class SensorConfig:
    """What the camera sees and how its depth is corrupted."""

    width: int = field(default=320, metadata=bounded(8, MAX_IMAGE_SIDE))
    """Image width in pixels."""
    height: int = field(default=240, metadata=bounded(8, MAX_IMAGE_SIDE))
    """Image height in pixels."""
    hfov_deg: float = field(default=REPLICA_HFOV_DEG, metadata=bounded(10, 170))
    """Horizontal field of view (Replica's 90 degrees by default)."""
    min_depth_m: float = field(default=0.1, metadata=bounded(0, 1000))
    """Closer surfaces read as missing depth."""
    max_depth_m: float = field(default=10.0, metadata=bounded(0, 1000, low_open=True))
    """Farther surfaces read as missing depth."""
    depth_noise_std_m: float = field(default=0.0, metadata=bounded(0, 10))
    """Gaussian depth noise at 1 m; grows with the square of depth (structured-light sensors). 0 = exact."""
    missing_depth_prob: float = field(default=0.0, metadata=bounded(0, 1))
    """Probability that a valid depth pixel is dropped (set to 0). 0 = none."""
    platform: str | None = None
    """GL platform, "egl" (default) or "osmesa"."""

    def intrinsics(self) -> Intrinsics:
        """Pinhole intrinsics of this camera."""
        if self.width < 8 or self.height < 8:
            raise ValueError(f"image must be at least 8x8 pixels, got {self.width}x{self.height}")
        if not 10.0 <= self.hfov_deg <= 170.0:
            raise ValueError(f"hfov_deg must be in [10, 170], got {self.hfov_deg}")
        return Intrinsics.from_fov(self.width, self.height, self.hfov_deg)


def encode_instance_color(instance_id: int) -> np.ndarray:
    """RGB uint8 that carries ``instance_id`` exactly through the segmentation pass (ids < 65536)."""
    return np.array([instance_id & 255, (instance_id >> 8) & 255, 0], dtype=np.uint8)


def decode_instance_image(seg_rgb: np.ndarray) -> np.ndarray:
    """Inverse of ``encode_instance_color`` on a (H, W, 3) image; returns (H, W) int32."""
    return seg_rgb[..., 0].astype(np.int32) + (seg_rgb[..., 1].astype(np.int32) << 8)


class RGBDSensor:
    """Renders frames of one scene. Keep one per process and reuse it: building the GL scene is the cost."""

    def __init__(self, scene: Scene, config: SensorConfig | None = None, seed: int | None = None):
        self.config = config or SensorConfig()
        self.intrinsics = self.config.intrinsics()
        self._rng = np.random.default_rng(seed)
        pyrender = load_pyrender(self.config.platform)
        self._pyrender = pyrender
        # Two GL scenes: the colour pass draws the whole room as one mesh (one draw call: pyrender's
        # per-mesh uniform updates are the cost otherwise); the segmentation pass needs a node per
        # instance so that seg_node_map can give each its own colour code.
        self._color_scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 1.0], ambient_light=[0.45, 0.45, 0.45])
        self._color_scene.add(pyrender.Mesh.from_trimesh(scene.mesh(), smooth=False))
        self._seg_scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 1.0])
        self._seg_map = {}
        for inst in scene.instances:
            node = self._seg_scene.add(pyrender.Mesh.from_trimesh(inst.mesh, smooth=False),
                                       name=f"instance_{inst.instance_id}")
            self._seg_map[node] = encode_instance_color(inst.instance_id)
        k = self.intrinsics
        # pyrender's projection puts pixel centres at half-integers; shift by half a pixel so that pixel
        # (u, v) sees the ray through image coordinates (u, v), the OpenCV convention of Frame.
        self._camera = pyrender.IntrinsicsCamera(
            fx=k.fx, fy=k.fy, cx=k.cx + 0.5, cy=k.cy + 0.5, znear=0.02, zfar=self.config.max_depth_m * 2
        )
        self._camera_nodes = [sc.add(self._camera, pose=np.eye(4)) for sc in (self._color_scene, self._seg_scene)]
        # A head lamp travels with the camera, plus two ceiling lights, so no face is ever black.
        self._head_light = self._color_scene.add(pyrender.PointLight(color=np.ones(3), intensity=2.0), pose=np.eye(4),
                                                 name="light_head")
        sx, sy, sz = scene.size_m
        for number, fx_ in enumerate((0.3, 0.7)):
            pose = np.eye(4)
            pose[:3, 3] = [sx * fx_, sy * 0.5, sz - 0.2]
            self._color_scene.add(pyrender.PointLight(color=np.ones(3), intensity=10.0), pose=pose, name=f"light_{number}")
        # One renderer per GL scene: a renderer frees the buffers of meshes not in the scene it draws,
        # so alternating scenes on one renderer would upload the geometry again every frame.
        self._renderers = [pyrender.OffscreenRenderer(k.width, k.height) for _ in range(2)]

    def render(self, pose: np.ndarray, index: int = 0, timestamp: float | None = None) -> Frame:
        """Render one frame at camera-to-world ``pose`` (4x4, OpenCV axes)."""
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise ValueError(f"pose must be a finite 4x4 camera-to-world matrix, got shape {pose.shape}")
        gl_pose = pose @ OPENCV_TO_OPENGL
        self._color_scene.set_pose(self._camera_nodes[0], gl_pose)
        self._seg_scene.set_pose(self._camera_nodes[1], gl_pose)
        self._color_scene.set_pose(self._head_light, gl_pose)
        rgb, depth = self._renderers[0].render(self._color_scene)
        seg, _ = self._renderers[1].render(self._seg_scene, flags=self._pyrender.RenderFlags.SEG,
                                           seg_node_map=self._seg_map)
        instance = decode_instance_image(seg)
        depth = self._corrupt_depth(depth.astype(np.float32))
        return Frame(
            rgb=np.ascontiguousarray(rgb[..., :3], dtype=np.uint8),
            depth=depth,
            pose=pose.copy(),
            intrinsics=self.intrinsics,
            instance=instance,
            timestamp=float(index if timestamp is None else timestamp),
            index=index,
        )

    def _corrupt_depth(self, depth: np.ndarray) -> np.ndarray:
        cfg = self.config
        out = depth.copy()
        out[(out < cfg.min_depth_m) | (out > cfg.max_depth_m)] = 0.0
        valid = out > 0
        if cfg.depth_noise_std_m > 0:
            noise = self._rng.normal(0.0, 1.0, out.shape).astype(np.float32)
            out[valid] += (cfg.depth_noise_std_m * out[valid] ** 2) * noise[valid]
        if cfg.missing_depth_prob > 0:
            out[valid & (self._rng.random(out.shape) < cfg.missing_depth_prob)] = 0.0
        return out

    def close(self) -> None:
        """Release the GL context."""
        for renderer in getattr(self, "_renderers", []):
            renderer.delete()
        self._renderers = []

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001  (GL teardown at interpreter exit may already be gone)
            pass
