"""The keyframe buffer and per-instance ray sampling from it (vMAP's training data).

Each keyframe keeps its RGB-D image, pose and instance image. For every instance the buffer indexes the
pixels where the instance was seen ("own" pixels: target occupancy 1, depth and colour supervised) and
the pixels of other surfaces inside the instance's 2D box ("other" pixels: the space in front of that
surface is free, so the instance must render occupancy 0 up to it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from mapping.data import Frame

MIN_MASK_PIXELS = 100  # OpenObj drops masks under 100 pixels
BOX_MARGIN_PX = 10  # the 2D box of an instance is grown by this much to find "other" pixels


@dataclass
class InstanceRays:
    """Rays of one training step for a batch of instances, each (N, R, ...) with R rays per instance.

    Attributes:
        origins, directions: (N, R, 3) world; directions have unit z in the camera (depth = t).
        depth: (N, R) observed depth (metres; 0 = none).
        rgb: (N, R, 3) in [0, 1].
        own: (N, R) bool, the pixel belongs to the instance (target occupancy 1).
    """

    origins: torch.Tensor
    directions: torch.Tensor
    depth: torch.Tensor
    rgb: torch.Tensor
    own: torch.Tensor


@dataclass
class _Pool:
    """Pixel indices of several keyframes concatenated, with each keyframe's offset and size."""

    pixels: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    offsets: list[int] = field(default_factory=list)
    sizes: list[int] = field(default_factory=list)

    def append(self, px: np.ndarray) -> None:
        self.offsets.append(len(self.pixels))
        self.sizes.append(len(px))
        self.pixels = np.concatenate([self.pixels, px.astype(np.int64)])

    def draw(self, entries: np.ndarray, generator: np.random.Generator) -> np.ndarray:
        """One random pixel of each listed keyframe entry (entries with an empty pool give -1)."""
        sizes = np.asarray(self.sizes)[entries]
        pick = np.asarray(self.offsets)[entries] + np.floor(generator.random(len(entries)) * sizes).astype(np.int64)
        return np.where(sizes > 0, self.pixels[np.minimum(pick, max(len(self.pixels) - 1, 0))], -1)


@dataclass
class _PixelIndex:
    own: _Pool = field(default_factory=_Pool)
    other: _Pool = field(default_factory=_Pool)
    keyframes: list[int] = field(default_factory=list)


class KeyframeBuffer:
    """Keyframes in memory as tensors, with per-instance pixel indices for sampling."""

    def __init__(self, device: torch.device | str = "cpu"):
        self.device = torch.device(device)
        self.rgb = torch.zeros(0, 0, 3, device=self.device)  # (K, H*W, 3) in [0, 1]
        self.depth = torch.zeros(0, 0, device=self.device)  # (K, H*W) metres
        self.poses = torch.zeros(0, 4, 4, device=self.device)  # (K, 4, 4) camera-to-world
        self.rays_cam: torch.Tensor | None = None  # (H*W, 3) camera directions, z = 1
        self.index: dict[int, _PixelIndex] = {}
        self.frame_indices: list[int] = []

    def __len__(self) -> int:
        return len(self.poses)

    def add(self, frame: Frame, instance: np.ndarray) -> list[int]:
        """Store a keyframe with its (corrected) instance image; returns the instance ids it indexed."""
        k = frame.intrinsics
        h, w = frame.depth.shape
        if self.rays_cam is None:
            v, u = np.mgrid[0:h, 0:w]
            cam = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u, dtype=np.float64)], -1)
            self.rays_cam = torch.as_tensor(cam.reshape(-1, 3), dtype=torch.float32, device=self.device)
        elif self.rays_cam.shape[0] != h * w:
            raise ValueError(f"frame {frame.index}: image size {w}x{h} differs from the earlier keyframes")
        kf = len(self.poses)
        rgb = torch.as_tensor(frame.rgb.reshape(1, -1, 3), device=self.device).float() / 255.0
        depth = torch.as_tensor(frame.depth.reshape(1, -1), dtype=torch.float32, device=self.device)
        pose = torch.as_tensor(frame.pose[None], dtype=torch.float32, device=self.device)
        self.rgb = rgb if kf == 0 else torch.cat([self.rgb, rgb])
        self.depth = depth if kf == 0 else torch.cat([self.depth, depth])
        self.poses = torch.cat([self.poses, pose])
        self.frame_indices.append(frame.index)
        valid = frame.depth > 0
        seen = []
        ids, counts = np.unique(instance[valid], return_counts=True)
        for iid, n in zip(ids.tolist(), counts.tolist()):
            if iid == 0 or n < MIN_MASK_PIXELS:
                continue
            mask = (instance == iid) & valid
            rows, cols = np.nonzero(mask)
            r0, r1 = max(rows.min() - BOX_MARGIN_PX, 0), min(rows.max() + BOX_MARGIN_PX + 1, h)
            c0, c1 = max(cols.min() - BOX_MARGIN_PX, 0), min(cols.max() + BOX_MARGIN_PX + 1, w)
            box = np.zeros_like(mask)
            box[r0:r1, c0:c1] = True
            other = box & ~mask & valid
            entry = self.index.setdefault(iid, _PixelIndex())
            entry.own.append(np.flatnonzero(mask))
            entry.other.append(np.flatnonzero(other))
            entry.keyframes.append(kf)
            seen.append(iid)
        return seen

    def sample(self, instance_ids: list[int], n_rays: int, own_fraction: float, generator: np.random.Generator
               ) -> InstanceRays:
        """``n_rays`` rays per instance from random keyframes that saw it: ``own_fraction`` of them on the
        instance, the rest on other surfaces inside its 2D box."""
        n_own = int(round(n_rays * own_fraction))
        kf_all, px_all, own_all = [], [], []
        for iid in instance_ids:
            entry = self.index[iid]
            picks = generator.integers(len(entry.keyframes), size=n_rays)
            own_px = entry.own.draw(picks, generator)
            other_px = entry.other.draw(picks, generator)
            own = (np.arange(n_rays) < n_own) | (other_px < 0)
            kf_all.append(np.asarray(entry.keyframes)[picks])
            px_all.append(np.where(own, own_px, other_px))
            own_all.append(own)
        kf = torch.as_tensor(np.stack(kf_all), device=self.device)  # (N, R)
        px = torch.as_tensor(np.stack(px_all), device=self.device)  # (N, R)
        poses = self.poses[kf]  # (N, R, 4, 4)
        directions = (poses[..., :3, :3] @ self.rays_cam[px].unsqueeze(-1)).squeeze(-1)  # (N, R, 3)
        return InstanceRays(
            origins=poses[..., :3, 3],
            directions=directions,
            depth=self.depth[kf, px],
            rgb=self.rgb[kf, px],
            own=torch.as_tensor(np.stack(own_all), device=self.device),
        )
