"""The map against the sensor, no mesh of the scene needed: each agent's meshed map ray cast from the
poses of its own input frames and compared with the depth the sensor measured there.

Two numbers tell a user at once whether a map is clean, on any data (a real recording has no ground-truth
mesh): the median depth error over the pixels where both the sensor and the map have a surface, and the
share of the sensor's valid pixels where the map is off by more than ``tolerance_m`` or has no surface
at all (holes and missing objects count against it; floaters in front of the surface show as errors).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Sequence

import numpy as np
import trimesh

from mapping.data.frame import Frame
from mapping.evaluate.raycast import MeshRaycaster

OFF_TOLERANCE_M = 0.05
"""A pixel whose map depth differs from the sensor's by more than this is off."""


@dataclass(frozen=True)
class DepthCheck:
    """The map's depth from the input poses against the sensor's."""

    median_cm: float | None
    """Median |map - sensor| depth (cm) where both have a surface (None: nowhere)."""
    off_pct: float | None
    """Share (%) of the sensor's valid pixels with the map off by more than the tolerance or with no surface
    (None: no valid pixel)."""
    no_surface_pct: float | None
    """Of those, the share (%) of valid pixels where the map has no surface at all."""
    pixels: int
    """Valid sensor pixels compared."""
    views: int

    def as_dict(self) -> dict:
        return asdict(self)


def depth_errors(raycaster: MeshRaycaster | None, frame: Frame, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """(h, w) images of ``frame``'s every ``stride``-th pixel: the map's depth error in metres (NaN where the
    map has no surface; no ``raycaster``: no surface anywhere) and whether the sensor has a valid depth."""
    sensor = np.asarray(frame.depth, np.float32)[::stride, ::stride]
    valid = np.isfinite(sensor) & (sensor > 0)
    if raycaster is None:
        return np.full(sensor.shape, np.nan, np.float32), valid
    map_depth, _ = raycaster.render_depth(np.asarray(frame.pose, np.float64), frame.intrinsics, stride=stride)
    return np.where(map_depth > 0, np.abs(map_depth - sensor), np.nan), valid


def _raycaster(mesh: trimesh.Trimesh | None) -> MeshRaycaster | None:
    return MeshRaycaster(mesh) if mesh is not None and len(mesh.faces) > 0 else None


INVALID, RIGHT, OFF, NO_SURFACE = 0, 1, 2, 3
"""The classes of ``depth_classes``: no valid sensor depth, map within the tolerance, off, no surface."""


def depth_classes(mesh: trimesh.Trimesh | None, frame: Frame, stride: int,
                  tolerance_m: float = OFF_TOLERANCE_M) -> np.ndarray:
    """(h, w) int8 image of the pixels' classes (``RIGHT``, ``OFF``, ``NO_SURFACE``, ``INVALID``) for the
    picture of where a map is wrong."""
    error, valid = depth_errors(_raycaster(mesh), frame, stride)
    classes = np.full(error.shape, NO_SURFACE, np.int8)
    hit = np.isfinite(error)
    classes[hit] = np.where(error[hit] <= tolerance_m, RIGHT, OFF)
    classes[~valid] = INVALID
    return classes


def depth_check(mesh: trimesh.Trimesh | None, frames: Sequence[Frame], stride: int = 4,
                tolerance_m: float = OFF_TOLERANCE_M) -> DepthCheck:
    """Ray cast ``mesh`` from every frame's pose and compare with the frame's depth (see the module doc).

    An empty or missing mesh has no surface anywhere: every valid pixel is off."""
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    if not frames:
        return DepthCheck(None, None, None, 0, 0)
    raycaster = _raycaster(mesh)
    error = np.concatenate([e[valid] for e, valid in (depth_errors(raycaster, f, stride) for f in frames)])
    if error.size == 0:
        return DepthCheck(None, None, None, 0, len(frames))
    hit = np.isfinite(error)
    off = ~hit | (np.where(hit, error, 0.0) > tolerance_m)
    return DepthCheck(float(np.median(error[hit]) * 100.0) if hit.any() else None, float(off.mean() * 100.0),
                      float((~hit).mean() * 100.0), int(error.size), len(frames))
