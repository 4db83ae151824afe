"""Bytes of the batch alignment's exchange: every agent sends its down-sampled instance clouds once
over each of its links (paper, sec. III-C), and ``align_agents`` reports what they carried.

Beside the alignment study because only the batch alignment counts bytes this way; the team's
online exchange counts the length of each serialised message (``mapping.team.channel``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from mapping.perception.types import AgentInstance

FLOAT32_BYTES = 4
"""xyz, features and confidence travel as float32."""
ID_BYTES = 4
"""The local instance id travels as int32."""


def instance_message_bytes(n_points: int, caption_dim: int, visual_dim: int | None) -> int:
    """Bytes of one instance in an alignment message.

    float32 xyz per point + the caption feature + the visual feature when present + the confidence
    (float32) + the local id (int32).
    """
    features = caption_dim + (visual_dim or 0)
    return FLOAT32_BYTES * (3 * n_points + features + 1) + ID_BYTES


def message_bytes(instances: Sequence[AgentInstance], clouds: Sequence[np.ndarray]) -> int:
    """Bytes of one agent's whole alignment message: its instances with their down-sampled clouds."""
    if len(instances) != len(clouds):
        raise ValueError(f"{len(instances)} instances but {len(clouds)} clouds")
    total = 0
    for inst, cloud in zip(instances, clouds):
        visual = None if inst.visual_feature is None else int(np.asarray(inst.visual_feature).size)
        total += instance_message_bytes(len(cloud), int(np.asarray(inst.caption_feature).size), visual)
    return total
