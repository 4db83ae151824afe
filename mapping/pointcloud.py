"""Small point-cloud functions shared by fusion and alignment (one implementation of each)."""

from __future__ import annotations

import numpy as np


def check_points(points: np.ndarray, what: str = "points") -> np.ndarray:
    """(n, 3) float64 copy-free view of ``points``; ValueError naming ``what`` for bad shape or NaN."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{what} must be an (n, 3) array, got shape {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{what} contain NaN or infinite coordinates")
    return points


def voxel_downsample(points: np.ndarray, voxel_m: float, groups: np.ndarray | None = None):
    """One point (the mean) per occupied voxel, separately per group when ``groups`` is given.

    Args:
        points: (n, 3) float64.
        voxel_m: voxel edge in metres (> 0).
        groups: optional (n,) non-negative int labels; points of different groups never share a voxel.

    Returns:
        (m, 3) float64 points ordered by (group, voxel key), deterministic; with ``groups``, also the
        (m,) group of each point (sorted ascending).
    """
    if not voxel_m > 0:
        raise ValueError(f"voxel size must be positive, got {voxel_m}")
    points = check_points(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    g = np.zeros(len(points), np.int64) if groups is None else np.asarray(groups, np.int64)
    if len(points) == 0:
        return points if groups is None else (points, g)
    keys = np.floor(points / voxel_m).astype(np.int64)
    keys -= keys.min(axis=0)
    dims = keys.max(axis=0) + 1
    cells = int(np.prod(dims))
    flat = g * cells + (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    uniq, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    means = np.stack([np.bincount(inverse, weights=points[:, a], minlength=len(uniq)) for a in range(3)], axis=1)
    means /= counts[:, None]
    return means if groups is None else (means, uniq // cells)
