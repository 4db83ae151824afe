"""Options of the Cross-Agent Instance Alignment (paper, sec. III-C): thresholds and sizes.

Shared by the online alignment on arrival (``mapping.team.arrival``), which applies the Instance
Collaborative Graph's edge rules, and by the batch alignment beside its benchmark
(``benchmarks.batch_alignment``), which also splits under-segmented instances.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class AlignmentConfig:
    """Options of the cross-agent alignment (defaults discussed in ``overlap``'s docstring)."""

    voxel_size_m: float = 0.02
    """Voxel of the down-sampling before clouds are sent."""
    overlap_radius_m: float = 0.02
    """Eq. 3-4: a point overlaps when its nearest neighbour in the other cloud is this close (>= voxel)."""
    iou_threshold: float = 0.25
    """Graph edge when IoU >= this (eq. 3)."""
    iob_threshold: float = 0.5
    """Graph edge when IoB in either direction >= this (eq. 4): partial views and pieces."""
    split_iob_threshold: float = 0.6
    """A cloud is a piece of another when its IoB into it >= this (over- / under-segmentation test)..."""
    split_share_threshold: float = 0.2
    """... or when it holds at least this share of the other's points (a partly seen coarse instance)."""
    split_min_piece_share: float = 0.02
    """... and a piece must hold at least this share of the split cloud's points or be seen better than
    it (not a sliver lying flat on it, like a window frame on a wall)."""
    split_min_points: int = 50
    """... and both the split cloud and its pieces need this many (down-sampled) points."""
    split_radius_m: float = 0.05
    """Points of a split instance farther than this from every reference form a remainder piece."""
    min_remainder_fraction: float = 0.1
    """A remainder piece needs at least this share of the split cloud (else it joins the nearest)."""
    max_split_rounds: int = 3
    """Split, re-measure and split again at most this often (nested under-segmentation)."""
    partial_iob_threshold: float = 0.08
    """Partial-view edge (graph.py): IoB in either direction >= this, with ... (1.0 = the paper's graph only)"""
    partial_similarity: float = 0.6
    """... caption cosine >= this ..."""
    partial_min_points: int = 30
    """... and at least this many overlapping points."""
    flat_size_ratio: float = 10.0
    """No IoB edge between a cloud and one this many times larger ... (graph.py: a picture on a wall)"""
    flat_similarity: float = 0.3
    """... whose captions' cosine is below this."""

    def __post_init__(self) -> None:
        if not self.voxel_size_m > 0 or self.overlap_radius_m < 0 or self.split_radius_m < 0:
            raise ValueError("voxel_size_m must be > 0 and the radii >= 0")
        for name in ("iou_threshold", "iob_threshold", "split_iob_threshold", "split_share_threshold"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        if not 0.0 <= self.min_remainder_fraction <= 1.0 or self.max_split_rounds < 0:
            raise ValueError("min_remainder_fraction must be in [0, 1] and max_split_rounds >= 0")
