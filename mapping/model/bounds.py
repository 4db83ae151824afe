"""Per-instance bounds: the box each instance's network lives in, grown as the instance is seen more.

Axis-aligned boxes of the back-projected points of an instance (robust percentiles, so a few stray
mask pixels at depth edges do not blow the box up), padded, at least ``min_side_m`` a side (vMAP: 10 cm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_SIDE_M = 0.10  # vMAP's smallest object box side
PAD_M = 0.05  # room around the observed points for the unseen back side and sampling near the surface
OUTLIER_PERCENTILE = 0.5  # percent of points ignored at each end per axis (mask-edge flying pixels)


@dataclass
class InstanceBound:
    """An axis-aligned box, (3,) ``lo`` and ``hi`` in world metres."""

    lo: np.ndarray
    hi: np.ndarray

    @staticmethod
    def from_points(points: np.ndarray, pad_m: float = PAD_M, min_side_m: float = MIN_SIDE_M) -> "InstanceBound":
        """Box of ``points`` ((n, 3), n >= 1), robust to a few outliers, padded, with a minimum side."""
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
            raise ValueError(f"points must be a non-empty (n, 3) array, got shape {points.shape}")
        if len(points) >= 200:
            lo = np.percentile(points, OUTLIER_PERCENTILE, axis=0)
            hi = np.percentile(points, 100 - OUTLIER_PERCENTILE, axis=0)
        else:
            lo, hi = points.min(axis=0), points.max(axis=0)
        lo, hi = lo - pad_m, hi + pad_m
        centre, half = (lo + hi) / 2, np.maximum((hi - lo) / 2, min_side_m / 2)
        return InstanceBound(centre - half, centre + half)

    def union(self, other: "InstanceBound") -> "InstanceBound":
        """Smallest box containing both (bounds only grow)."""
        return InstanceBound(np.minimum(self.lo, other.lo), np.maximum(self.hi, other.hi))

    @property
    def size(self) -> np.ndarray:
        """(3,) side lengths."""
        return self.hi - self.lo

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool for (n, 3) points."""
        return np.all((points >= self.lo) & (points <= self.hi), axis=-1)
