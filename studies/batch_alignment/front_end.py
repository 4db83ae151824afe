"""The offline open-vocabulary front end of a simulated team: segment -> caption -> encode -> fuse,
every frame of every agent at once (``perceive_team``, options in ``FrontEndConfig``).

This is the glue between the simulated world and ``mapping``'s perception and fusion that feeds the
batch alignment: aligning the team's instances by mode and its labelled point maps are in
``team_alignment``, semantic scoring in ``mapping.evaluate.semantic``, the world's semantic ground
truth and vocabulary in ``openmulti_env.world.semantics``. Run order (the paper's, sec. III-B/C): each
agent segments and fuses all its frames, then the agents that exchange instance point clouds align
them. Only the alignment study (``studies.alignment``) runs the team this way, so this
sits beside it; team runs perceive, fuse and align online, round by round (``mapping.team``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from tqdm import tqdm

from studies.batch_alignment.team_alignment import TeamPerception
from mapping.alignment import AlignmentConfig
from mapping.fusion import FusionConfig, fuse_frames
from mapping.perception import TextEncoder, shared_text_encoder
from mapping.perception.errors import SegmentationErrorConfig
from mapping.perception.front_end import encode_segments
from mapping.perception.image_encoder import ImageTextEncoder
from mapping.perception.segmenter import OracleSegmenter
from openmulti_env.world.semantics import instance_anchor_points, instance_infos
from openmulti_env.world.world import World


@dataclass
class FrontEndConfig:
    """How the simulated front end sees the world."""

    errors: SegmentationErrorConfig = field(default_factory=SegmentationErrorConfig)
    """Per-agent segmentation / caption error rates (semantic, over-, under-segmentation, drops)."""
    fusion: FusionConfig = field(default_factory=FusionConfig)
    """Cross-frame fusion (OpenObj's thresholds)."""
    alignment: AlignmentConfig = field(default_factory=AlignmentConfig)
    """Cross-agent alignment thresholds."""


def perceive_team(world: World, seed: int, config: FrontEndConfig | None = None,
                  text_encoder: TextEncoder | None = None, progress: bool = True,
                  image_encoder: ImageTextEncoder | None = None) -> TeamPerception:
    """Render, segment (with the seeded error model), caption, encode and fuse every agent's frames.

    Masks get visual features only when an ``image_encoder`` (a local CLIP checkpoint) is given."""
    config = config or FrontEndConfig()
    encoder = text_encoder or shared_text_encoder()
    infos = instance_infos(world.scene)
    anchors = instance_anchor_points(world.scene, seed=seed)
    frames, segmentations, fused = {}, {}, {}
    for a in range(world.num_agents):
        name = f"agent_{a}"
        segmenter = OracleSegmenter(infos, config.errors, seed=seed, agent=a, anchor_points=anchors)
        agent_frames, agent_segs = [], []
        for i in tqdm(range(len(world.agent_poses[a])), desc=f"{name} perception", unit="frame", disable=not progress):
            frame = world.render(a, i)
            agent_frames.append(frame)
            agent_segs.append(encode_segments(segmenter.segment(frame), frame, encoder, image_encoder))
        frames[name], segmentations[name] = agent_frames, agent_segs
        fused[name] = fuse_frames(agent_frames, agent_segs, config.fusion)
    return TeamPerception(frames, segmentations, fused)
