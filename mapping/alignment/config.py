"""Options of the Cross-Agent Instance Alignment (paper, sec. III-C): thresholds and sizes.

Shared by the online alignment on arrival (``mapping.team.arrival``), which applies the Instance
Collaborative Graph's edge rules, and by the batch alignment beside its benchmark
(``studies.batch_alignment``), which also splits under-segmented instances.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mapping.config_fields import bounded


@dataclass(frozen=True)
class AlignmentConfig:
    """Options of the cross-agent alignment (defaults discussed in ``overlap``'s docstring)."""

    voxel_size_m: float = field(default=0.02, metadata=bounded(0, 10, low_open=True))
    """Voxel of the down-sampling before clouds are sent."""
    overlap_radius_m: float = field(default=0.02, metadata=bounded(0, 10))
    """Eq. 3-4: a point overlaps when its nearest neighbour in the other cloud is this close (>= voxel)."""
    iou_threshold: float = field(default=0.25, metadata=bounded(0, 1, low_open=True))
    """Graph edge when IoU >= this (eq. 3)."""
    iob_threshold: float = field(default=0.5, metadata=bounded(0, 1, low_open=True))
    """Graph edge when IoB in either direction >= this (eq. 4): partial views and pieces."""
    split_iob_threshold: float = field(default=0.6, metadata=bounded(0, 1, low_open=True))
    """A cloud is a piece of another when its IoB into it >= this (over- / under-segmentation test)..."""
    split_share_threshold: float = field(default=0.2, metadata=bounded(0, 1, low_open=True))
    """... or when it holds at least this share of the other's points (a partly seen coarse instance)."""
    split_min_piece_share: float = field(default=0.02, metadata=bounded(0, 1))
    """... and a piece must hold at least this share of the split cloud's points or be seen better than
    it (not a sliver lying flat on it, like a window frame on a wall)."""
    split_min_points: int = field(default=50, metadata=bounded(0, 10_000_000))
    """... and both the split cloud and its pieces need this many (down-sampled) points."""
    split_radius_m: float = field(default=0.05, metadata=bounded(0, 10))
    """Points of a split instance farther than this from every reference form a remainder piece."""
    min_remainder_fraction: float = field(default=0.1, metadata=bounded(0, 1))
    """A remainder piece needs at least this share of the split cloud (else it joins the nearest)."""
    max_split_rounds: int = field(default=3, metadata=bounded(0, 1000))
    """Split, re-measure and split again at most this often (nested under-segmentation)."""
    partial_iob_threshold: float = field(default=0.08, metadata=bounded(0, 1))
    """Partial-view edge (graph.py): IoB in either direction >= this, with ... (1.0 = the paper's graph only)"""
    partial_similarity: float = field(default=0.6, metadata=bounded(-1, 1))
    """... caption cosine >= this ..."""
    partial_min_points: int = field(default=30, metadata=bounded(0, 10_000_000))
    """... and at least this many overlapping points."""
    flat_size_ratio: float = field(default=10.0, metadata=bounded(0, 1e6, low_open=True))
    """No IoB edge between a cloud and one this many times larger ... (graph.py: a picture on a wall)"""
    flat_similarity: float = field(default=0.3, metadata=bounded(-1, 1))
    """... whose captions' cosine is below this."""

    def __post_init__(self) -> None:
        if not self.voxel_size_m > 0 or self.overlap_radius_m < 0 or self.split_radius_m < 0:
            raise ValueError("voxel_size_m must be > 0 and the radii >= 0")
        for name in ("iou_threshold", "iob_threshold", "split_iob_threshold", "split_share_threshold"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        if not 0.0 <= self.min_remainder_fraction <= 1.0 or self.max_split_rounds < 0:
            raise ValueError("min_remainder_fraction must be in [0, 1] and max_split_rounds >= 0")
