"""A team's perception (every agent's frames, masks and fused instances) aligned by mode, and its
corrected masks as a labelled point map, which scores an alignment without the neural map.

Nothing here needs a simulator: ``front_end.perceive_team`` fills a :class:`TeamPerception` from a
simulated world; any source of frames, segmentations and fusion results can. The alignment study
(``studies.alignment``) is its only user, so it sits beside it.

No PettingZoo, Gymnasium, pyrender or ``openmulti_env`` imports here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from studies.batch_alignment.align import AlignmentResult, align_agents, no_alignment
from studies.batch_alignment.oracle import oracle_alignment
from mapping.alignment.config import AlignmentConfig
from mapping.data import Frame
from mapping.perception.types import FrameSegmentation, FusionResult

__all__ = ["ALIGNMENT_MODES", "TeamPerception", "align_team", "labelled_points"]

ALIGNMENT_MODES = ("none", "paper", "oracle")
"""``none``: every agent keeps its own ids and meanings (no point clouds exchanged); ``paper``: the
Cross-Agent Instance Alignment of sec. III-C; ``oracle``: ground-truth ids (an upper bound)."""


@dataclass
class TeamPerception:
    """Every agent's frames, masks and fused instances (agent names ``agent_K``)."""

    frames: dict[str, list[Frame]]
    segmentations: dict[str, list[FrameSegmentation]]
    fused: dict[str, FusionResult]


def align_team(perception: TeamPerception, mode: str = "paper", config: AlignmentConfig | None = None) -> AlignmentResult:
    """Global ids for every agent's instances: ``none``, ``paper`` (sec. III-C) or ``oracle``."""
    args = (perception.fused, perception.frames, perception.segmentations)
    if mode == "paper":
        return align_agents(*args, config=config or AlignmentConfig())
    if mode == "none":
        return no_alignment(*args)
    if mode == "oracle":
        return oracle_alignment(*args)
    raise ValueError(f"unknown alignment {mode!r}; choose one of {ALIGNMENT_MODES}")


def labelled_points(perception: TeamPerception, alignment: AlignmentResult, agent: str,
                    frame_stride: int = 5, pixel_stride: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A semantic point map of one agent without the neural map: its corrected masks back-projected.

    Every ``frame_stride``-th frame, every ``pixel_stride``-th pixel; returns (m, 3) world points and
    their (m,) global ids. Used to score alignment on its own (the mapper's meshes are scored the
    same way in ``openmulti run``).
    """
    points, ids = [], []
    for frame in perception.frames[agent][::frame_stride]:
        labels = alignment.corrected_labels(agent, frame.index)
        frame_points, valid = frame.backproject_pixels(pixel_stride, mask=labels > 0)
        points.append(frame_points)
        ids.append(labels[::pixel_stride, ::pixel_stride][valid])
    if not points:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    return np.concatenate(points), np.concatenate(ids).astype(np.int64)
