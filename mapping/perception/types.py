"""Data that flows through the open-vocabulary front end, fusion and alignment.

Shapes in the docstrings are the types. Ids: ``0`` is "no mask" in every label image; a segment id is
local to one frame; a local instance id is local to one agent (after cross-frame fusion); a global id
names one physical object for the whole team (after cross-agent alignment).

``source_ids`` fields carry the simulator's ground truth along for diagnostics, benchmarks and the
``oracle`` alignment only: the method itself never reads them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class InstanceInfo:
    """What the simulator knows about one ground-truth instance (input of the oracle segmenter).

    Attributes:
        instance_id: the id in the ground-truth instance images (>= 1).
        category: noun class ("chair").
        caption: the scene's own description ("a wooden chair").
        color_name: main colour word ("red").
        material: material word ("wooden").
        is_structure: wall, floor or ceiling.
        touching: ids of instances whose surfaces touch this one (candidates for under-segmentation).
    """

    instance_id: int
    category: str
    caption: str
    color_name: str = ""
    material: str = ""
    is_structure: bool = False
    touching: tuple[int, ...] = ()


@dataclass
class Segment:
    """One mask of one frame, as the front end reports it.

    Attributes:
        segment_id: the mask's value in ``FrameSegmentation.labels`` (>= 1, unique in the frame).
        caption: the captioner's text for the mask.
        pixels: mask area in pixels.
        caption_feature: (384,) float32 unit SBERT vector of the caption, or None before encoding.
        visual_feature: (D,) float32 unit image-text vector of the crop, or None (no image encoder).
        source_ids: ground-truth ids under the mask, most pixels first (simulator only).
    """

    segment_id: int
    caption: str
    pixels: int
    caption_feature: np.ndarray | None = None
    visual_feature: np.ndarray | None = None
    source_ids: tuple[int, ...] = ()


@dataclass
class FrameSegmentation:
    """All masks of one frame.

    Attributes:
        frame_index: ``Frame.index`` of the frame they belong to.
        labels: (H, W) int32 segment ids, 0 = no mask.
        segments: one ``Segment`` per id present in ``labels``.
    """

    frame_index: int
    labels: np.ndarray
    segments: list[Segment] = field(default_factory=list)

    def segment(self, segment_id: int) -> Segment:
        """The segment with this id (KeyError naming the frame when absent)."""
        for s in self.segments:
            if s.segment_id == segment_id:
                return s
        raise KeyError(f"frame {self.frame_index} has no segment {segment_id}")


@dataclass
class AgentInstance:
    """One instance of one agent's map after cross-frame fusion (O_{k,i} of the paper).

    Attributes:
        local_id: the agent's id for it (>= 1).
        caption: representative caption text.
        caption_feature: (384,) float32 unit vector (fused over its masks).
        visual_feature: (D,) float32 unit vector, or None.
        confidence: eq. 1-2, mean over the agent's frames, in [0, 1].
        points: (P, 3) float64 world-frame points, voxel down-sampled.
        colour: (3,) mean rgb in [0, 1].
        observations: (frame_index, segment_id) pairs fused into it.
        source_ids: ground-truth ids of its points, most first (simulator only).
    """

    local_id: int
    caption: str
    caption_feature: np.ndarray
    visual_feature: np.ndarray | None
    confidence: float
    points: np.ndarray
    colour: np.ndarray
    observations: list[tuple[int, int]] = field(default_factory=list)
    source_ids: tuple[int, ...] = ()


@dataclass
class FusionResult:
    """One agent's instances after cross-frame fusion.

    Attributes:
        instances: local id -> fused instance.
        assignment: (frame_index, segment_id) -> local id, for every mask that was kept.
    """

    instances: dict[int, AgentInstance]
    assignment: dict[tuple[int, int], int]

    def label_image(self, segmentation: FrameSegmentation) -> np.ndarray:
        """(H, W) int32 local instance ids of one frame's masks (0 = none or a dropped mask)."""
        lut = np.zeros(int(segmentation.labels.max(initial=0)) + 1, np.int32)
        for seg in segmentation.segments:
            lut[seg.segment_id] = self.assignment.get((segmentation.frame_index, seg.segment_id), 0)
        return lut[segmentation.labels]
