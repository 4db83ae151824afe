"""The segmentation error model: the four front-end errors that cross-agent alignment exists to fix.

Semantic errors, over-segmentation and under-segmentation are decided ONCE per (seed, agent,
instance), like the systematic mistakes of a real segmenter looking at an object from one side of
the room: cross-frame fusion cannot average them away, only another agent's view can fix them
(paper, sec. III-C). Mask drops (viewpoint loss) are drawn per (seed, agent, frame, instance).
Every draw comes from its own ``numpy`` generator keyed by those integers, so the plan is
deterministic and one instance's draws never depend on the others, except that an under-segmentation
partner is chosen among the instances not already paired, in id order. A semantic error shows only
in views that cut the instance at the image border (``semantic_errors_in_partial_views``).

Structure (walls, floor, ceiling) gets no errors by default: CropFormer-like segmenters rarely miss
or mislabel a wall, and splitting or merging room planes is not what the paper's alignment targets.
``structure_errors=True`` lets semantic errors and drops (never over/under) reach them too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from mapping.perception.captioner import wrong_category
from mapping.perception.types import InstanceInfo

# Stream tags: one independent generator per (seed, agent, instance, kind of draw).
_SEMANTIC, _OVER, _UNDER, _DROP = 1, 2, 3, 4


@dataclass(frozen=True)
class SegmentationErrorConfig:
    """Error rates of one agent's simulated segmenter (each agent draws its own errors)."""

    semantic_rate: float = 0.15
    """Share of instances captioned as another, plausible category (persistent per agent)."""
    over_segmentation_rate: float = 0.10
    """Share of instances split into 2-3 masks along 1-2 world planes (instances not already merged)."""
    under_segmentation_rate: float = 0.10
    """Share of instances with a touching neighbour that share one mask with it (pairs)."""
    mask_drop_rate: float = 0.05
    """Probability that a visible instance's mask is missing from one frame (viewpoint loss)."""
    min_mask_pixels: int = 100
    """Masks with fewer pixels are dropped (OpenObj's threshold)."""
    structure_errors: bool = False
    """Also give walls, floor and ceiling semantic errors and drops (never over/under)."""
    semantic_errors_in_partial_views: bool = True
    """A confused instance is mis-captioned only in the views that show it truncated: its mask reaches
    the image's border band (eq. 1 below 1). A view with the whole mask in the central region gets the
    right caption. Captioners fail on partial views, and this is why the paper trusts the instance with
    the highest confidence as the reference; False = wrong in every view."""
    central_margin: float = 0.1
    """Border band, as a share of width / height, that makes a view partial (eq. 1's central region)."""

    def __post_init__(self) -> None:
        for name in ("semantic_rate", "over_segmentation_rate", "under_segmentation_rate", "mask_drop_rate"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0.0 <= value <= 1.0):
                raise ValueError(f"SegmentationErrorConfig.{name} must be in [0, 1], got {value!r}")
        if int(self.min_mask_pixels) < 1:
            raise ValueError(f"SegmentationErrorConfig.min_mask_pixels must be >= 1, got {self.min_mask_pixels!r}")

    @classmethod
    def none(cls, min_mask_pixels: int = 100) -> "SegmentationErrorConfig":
        """A perfect segmenter (only the minimum mask size applies)."""
        return cls(0.0, 0.0, 0.0, 0.0, min_mask_pixels)


@dataclass(frozen=True)
class ErrorPlan:
    """The persistent errors of one agent's segmenter.

    Attributes:
        wrong_category: instance id -> the category its captions describe instead (semantic error).
        over_pieces: instance id -> number of masks it is split into (2 or 3).
        plane_angles: instance id -> (2,) angles (radians) of the split planes' normals in the plane of
            the instance's two main axes; the second plane (60-120 degrees from the first) only splits
            the first plane's positive side.
        under_partner: instance id -> the touching instance sharing its mask (symmetric).
    """

    wrong_category: dict[int, str] = field(default_factory=dict)
    over_pieces: dict[int, int] = field(default_factory=dict)
    plane_angles: dict[int, np.ndarray] = field(default_factory=dict)
    under_partner: dict[int, int] = field(default_factory=dict)


def _rng(seed: int, agent: int, *keys: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(agent), *(int(k) for k in keys)])


def plan_errors(infos: Sequence[InstanceInfo], config: SegmentationErrorConfig, seed: int, agent: int) -> ErrorPlan:
    """Decide the persistent errors of agent ``agent``'s segmenter.

    Under-segmentation: each instance with a non-structure touching neighbour starts a merge with
    probability rate / 2 (so about ``rate`` of such instances end up in a merged pair), in ascending
    id order, with a seeded free neighbour; pairs are disjoint. Over-segmentation is drawn for the
    instances left unmerged.

    Args:
        infos: every instance the segmenter may see (ids unique, >= 1).
        config: the rates.
        seed, agent: non-negative integers keying every draw.
    """
    if int(seed) < 0 or int(agent) < 0:
        raise ValueError(f"seed and agent must be non-negative integers, got seed={seed}, agent={agent}")
    by_id = {info.instance_id: info for info in infos}
    if len(by_id) != len(infos) or any(i < 1 for i in by_id):
        raise ValueError("InstanceInfo ids must be unique and >= 1")
    scene_categories = sorted({info.category for info in infos})
    wrong: dict[int, str] = {}
    for iid in sorted(by_id):
        info = by_id[iid]
        if info.is_structure and not config.structure_errors:
            continue
        rng = _rng(seed, agent, iid, _SEMANTIC)
        if rng.random() < config.semantic_rate:
            wrong[iid] = wrong_category(info.category, rng, scene_categories)

    partner: dict[int, int] = {}
    for iid in sorted(by_id):
        info = by_id[iid]
        if info.is_structure or iid in partner:
            continue
        free = sorted(j for j in set(info.touching) if j in by_id and j != iid and j not in partner
                      and not by_id[j].is_structure)
        rng = _rng(seed, agent, iid, _UNDER)
        if free and rng.random() < config.under_segmentation_rate / 2.0:
            j = free[int(rng.integers(len(free)))]
            partner[iid], partner[j] = j, iid

    pieces: dict[int, int] = {}
    angles: dict[int, np.ndarray] = {}
    for iid in sorted(by_id):
        if by_id[iid].is_structure or iid in partner:
            continue
        rng = _rng(seed, agent, iid, _OVER)
        if rng.random() < config.over_segmentation_rate:
            pieces[iid] = 2 + int(rng.integers(2))
            first = rng.uniform(0.0, np.pi)  # the second plane crosses the first at 60-120 degrees
            angles[iid] = np.array([first, first + rng.uniform(np.pi / 3.0, 2.0 * np.pi / 3.0)])
    return ErrorPlan(wrong, pieces, angles, partner)


def mask_dropped(config: SegmentationErrorConfig, seed: int, agent: int, frame_index: int, instance_id: int) -> bool:
    """Whether the mask keyed by ``instance_id`` is missing from frame ``frame_index`` (viewpoint loss)."""
    if config.mask_drop_rate <= 0.0:
        return False
    return bool(_rng(seed, agent, instance_id, _DROP, frame_index).random() < config.mask_drop_rate)


def split_labels(points: np.ndarray, anchor_points: np.ndarray, angles: np.ndarray, pieces: int) -> np.ndarray:
    """Piece index of each point of an over-segmented instance (the same world planes in every frame).

    The planes pass through the centroid of ``anchor_points``; their normals lie in the plane of its
    two main (PCA) axes, so they cut across the object's extent even for flat objects. The first plane
    splits the instance in two; with 3 pieces the second plane splits the first plane's positive side.

    Args:
        points : (n, 3) float64 world points of the instance in one frame.
        anchor_points : (m, 3) float64 world points defining the instance's centre and axes (m >= 3).
        angles : (2,) float normal angles in radians.
        pieces : 2 or 3.

    Returns:
        (n,) int64 piece index in [0, pieces).
    """
    anchor_points = np.asarray(anchor_points, np.float64)
    if anchor_points.ndim != 2 or anchor_points.shape[1] != 3 or len(anchor_points) < 3:
        raise ValueError(f"anchor_points must be (m >= 3, 3), got {anchor_points.shape}")
    if pieces not in (2, 3):
        raise ValueError(f"an over-segmented instance has 2 or 3 pieces, got {pieces}")
    centre = anchor_points.mean(axis=0)
    _, _, vt = np.linalg.svd(anchor_points - centre, full_matrices=False)
    e1, e2 = vt[0], vt[1]
    rel = np.asarray(points, np.float64) - centre
    normals = [np.cos(a) * e1 + np.sin(a) * e2 for a in angles[:2]]
    side1 = rel @ normals[0] >= 0.0
    labels = side1.astype(np.int64)
    if pieces == 3:
        labels[side1 & (rel @ normals[1] >= 0.0)] = 2
    return labels
