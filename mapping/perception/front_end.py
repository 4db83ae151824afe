"""Front-end glue: the caption (SBERT) and visual (CLIP-like) features of one frame's masks.

These are the per-mask features f^caption and f^clip of the paper (sec. III-B) that the code book
stores; captions are encoded in one batch per frame, crops likewise.
"""

from __future__ import annotations

from typing import Protocol, Sequence

import numpy as np

from mapping.data.frame import Frame
from mapping.perception.image_encoder import ImageTextEncoder, crop_for_mask
from mapping.perception.types import FrameSegmentation


class CaptionEncoder(Protocol):
    """A sentence encoder such as ``TextEncoder``."""

    def encode(self, texts: Sequence[str]) -> np.ndarray:
        """(n, D) float32 unit vectors."""
        ...


def encode_segments(segmentation: FrameSegmentation, frame: Frame, text_encoder: CaptionEncoder,
                    image_encoder: ImageTextEncoder | None = None) -> FrameSegmentation:
    """Fill ``caption_feature`` (and ``visual_feature`` when an image encoder is given) of every segment.

    Works in place and returns ``segmentation`` for chaining. Visual features come from the RGB crop
    of each mask's bounding box padded by 20 px (OpenObj); without an image encoder they stay None.
    """
    if segmentation.labels.shape != frame.depth.shape:
        raise ValueError(f"segmentation of frame {segmentation.frame_index} has labels {segmentation.labels.shape}, "
                         f"frame {frame.index} is {frame.depth.shape}")
    segments = segmentation.segments
    if not segments:
        return segmentation
    captions = np.asarray(text_encoder.encode([s.caption for s in segments]), np.float32)
    if captions.shape[0] != len(segments):
        raise ValueError(f"text encoder returned {captions.shape[0]} features for {len(segments)} captions")
    for seg, feature in zip(segments, captions):
        seg.caption_feature = feature
    if image_encoder is not None:
        crops = [crop_for_mask(frame.rgb, segmentation.labels == s.segment_id) for s in segments]
        visual = np.asarray(image_encoder.encode_images(crops), np.float32)
        if visual.shape[0] != len(segments):
            raise ValueError(f"image encoder returned {visual.shape[0]} features for {len(segments)} crops")
        for seg, feature in zip(segments, visual):
            seg.visual_feature = feature
    return segmentation
