"""The RGB-D frame and the per-agent sequence shared by the simulator and the dataset loaders.

Conventions (the same as vMAP's Replica and ScanNet data):
- ``pose`` is camera-to-world, 4x4, OpenCV camera axes (x right, y down, z forward);
- ``depth`` is metric (metres), 0 where the sensor gave no reading;
- ``instance`` is an integer image, 0 = no instance;
- pixel (u, v) has its centre at image coordinates (u, v) (OpenCV), so a camera point (x, y, z) lands
  on u = fx * x / z + cx.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator, Sequence

import numpy as np


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of an image of ``width`` x ``height`` pixels."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def matrix(self) -> np.ndarray:
        """(3, 3) float64 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width: int, height: int) -> "Intrinsics":
        """The same camera resampled to ``width`` x ``height`` pixels."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(width, height, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy)

    @staticmethod
    def from_fov(width: int, height: int, hfov_deg: float) -> "Intrinsics":
        """Square-pixel camera with horizontal field of view ``hfov_deg``, centred principal point."""
        fx = 0.5 * width / np.tan(np.radians(hfov_deg) / 2.0)
        return Intrinsics(width, height, fx, fx, width / 2.0, height / 2.0)


def central_region(height: int, width: int, border_margin: float) -> tuple[int, int, int, int]:
    """(v0, v1, u0, u1): the image's central region, rows v0 <= v < v1 and columns u0 <= u < u1, after
    a border band of ``border_margin`` x height / width (the "central region" of the paper's eq. 1)."""
    if not 0.0 <= border_margin < 0.5:
        raise ValueError(f"border_margin must be in [0, 0.5), got {border_margin}")
    mv, mu = int(round(border_margin * height)), int(round(border_margin * width))
    return mv, height - mv, mu, width - mu


@dataclass
class Frame:
    """One RGB-D observation of one agent.

    Attributes:
        rgb: (H, W, 3) uint8.
        depth: (H, W) float32 metres, 0 = missing.
        pose: (4, 4) float64 camera-to-world (OpenCV axes).
        intrinsics: the camera.
        instance: (H, W) int32 instance ids (0 = none), or None when the data has none.
        timestamp: seconds (or frame index when the data has no clock).
        index: position of the frame in its source sequence.
    """

    rgb: np.ndarray
    depth: np.ndarray
    pose: np.ndarray
    intrinsics: Intrinsics
    instance: np.ndarray | None = None
    timestamp: float = 0.0
    index: int = 0

    def __post_init__(self) -> None:
        h, w = self.intrinsics.height, self.intrinsics.width
        if self.rgb.shape != (h, w, 3) or self.rgb.dtype != np.uint8:
            raise ValueError(f"Frame {self.index}: rgb must be uint8 ({h}, {w}, 3), got {self.rgb.dtype} {self.rgb.shape}")
        if self.depth.shape != (h, w):
            raise ValueError(f"Frame {self.index}: depth must be ({h}, {w}), got {self.depth.shape}")
        if self.pose.shape != (4, 4) or not np.all(np.isfinite(self.pose)):
            raise ValueError(f"Frame {self.index}: pose must be a finite 4x4 matrix")
        if self.instance is not None and self.instance.shape != (h, w):
            raise ValueError(f"Frame {self.index}: instance image must be ({h}, {w}), got {self.instance.shape}")

    def backproject(self, stride: int = 1, mask: np.ndarray | None = None) -> np.ndarray:
        """World points of the valid depth pixels.

        Args:
            stride: take every ``stride``-th pixel in both directions.
            mask: optional (H, W) bool; only pixels where it is True.

        Returns:
            (n, 3) float64 world points.
        """
        return backproject_depth(self.depth, self.intrinsics, self.pose, stride=stride, mask=mask)

    def backproject_pixels(self, stride: int = 1, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """World points of the valid depth pixels and the (strided) grid of those pixels; see
        ``backproject_pixels``."""
        return backproject_pixels(self.depth, self.intrinsics, self.pose, stride=stride, mask=mask)


def backproject_pixels(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    pose: np.ndarray,
    stride: int = 1,
    mask: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Back-project a metric depth image to world points, and say which pixels they came from.

    Args:
        depth: (H, W) metres, 0 or non-finite = invalid.
        intrinsics: camera of the image.
        pose: (4, 4) camera-to-world, OpenCV axes.
        stride: pixel step in both directions.
        mask: optional (H, W) bool selecting pixels.

    Returns:
        points: (n, 3) float64 world points, one per valid selected pixel, row-major.
        valid: (ceil(H / stride), ceil(W / stride)) bool, True at those pixels of the strided grid,
            so ``image[::stride, ::stride][valid]`` gives any per-pixel value in the order of ``points``.
    """
    d = depth[::stride, ::stride].astype(np.float64)
    v, u = np.mgrid[0 : depth.shape[0] : stride, 0 : depth.shape[1] : stride]
    valid = np.isfinite(d) & (d > 0)
    if mask is not None:
        valid &= mask[::stride, ::stride]
    z = d[valid]
    x = (u[valid] - intrinsics.cx) / intrinsics.fx * z
    y = (v[valid] - intrinsics.cy) / intrinsics.fy * z
    cam = np.stack([x, y, z], axis=1)
    return cam @ pose[:3, :3].T + pose[:3, 3], valid


def backproject_depth(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    pose: np.ndarray,
    stride: int = 1,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """(n, 3) float64 world points of the valid selected pixels (``backproject_pixels`` without the grid)."""
    return backproject_pixels(depth, intrinsics, pose, stride, mask)[0]


@dataclass
class AgentSequence:
    """The private frames of one agent, in time order, with the scene they came from.

    ``frames`` is any sequence: a list in memory, or a loader's lazy sequence that reads each frame
    from disk when indexed, so a long real sequence need not be in memory at once.
    """

    agent_id: int
    frames: Sequence[Frame] = field(default_factory=list)
    name: str = ""

    def __len__(self) -> int:
        return len(self.frames)

    def __iter__(self) -> Iterator[Frame]:
        return iter(self.frames)

    def __getitem__(self, i: int) -> Frame:
        return self.frames[i]

    @property
    def poses(self) -> np.ndarray:
        """(n, 4, 4) camera-to-world poses of all frames (without reading images when the loader can)."""
        lazy_poses = getattr(self.frames, "poses", None)
        if lazy_poses is not None:
            return np.asarray(lazy_poses)
        return np.stack([f.pose for f in self.frames]) if len(self.frames) else np.zeros((0, 4, 4))


def split_contiguous(n_frames: int, n_agents: int) -> list[range]:
    """Split ``n_frames`` frame indices into ``n_agents`` contiguous chunks of near-equal length.

    This is the paper's setting: one recorded sequence cut into K consecutive pieces, one per agent.
    """
    if n_agents < 1:
        raise ValueError(f"n_agents must be >= 1, got {n_agents}")
    if n_frames < n_agents:
        raise ValueError(f"cannot split {n_frames} frames among {n_agents} agents")
    edges = np.linspace(0, n_frames, n_agents + 1).round().astype(int)
    return [range(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]
