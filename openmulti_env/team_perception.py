"""The open-vocabulary front end of a simulated team, end to end: segment -> caption -> encode -> fuse
per agent, then align across agents; and the semantic scoring of what the team built.

This is the glue between the simulated world and ``mapping``'s perception, fusion, alignment and
semantic evaluation; each of those knows nothing of the world. Run order (the paper's, sec. III-B/C):
each agent segments and fuses all its frames, then the agents that exchange instance point clouds
align them, and the mapper trains on the corrected masks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from mapping.alignment import AlignmentConfig, AlignmentResult, align_agents, no_alignment, oracle_alignment
from mapping.data import Frame
from mapping.evaluate.semantic import SemanticMetrics, semantic_metrics, zero_shot_labels
from mapping.fusion import FusionConfig, fuse_frames
from mapping.perception import CodeBook, FrameSegmentation, FusionResult, TextEncoder, shared_text_encoder
from mapping.perception.errors import SegmentationErrorConfig
from mapping.perception.front_end import encode_segments
from mapping.perception.image_encoder import ImageTextEncoder
from mapping.perception.segmenter import OracleSegmenter
from openmulti_env.world.scene import STRUCTURE_CATEGORIES
from openmulti_env.world.semantics import instance_anchor_points, instance_infos
from openmulti_env.world.world import World

ALIGNMENT_MODES = ("none", "paper", "oracle")
"""``none``: every agent keeps its own ids and meanings (no point clouds exchanged); ``paper``: the
Cross-Agent Instance Alignment of sec. III-C; ``oracle``: ground-truth ids (an upper bound)."""


@dataclass
class FrontEndConfig:
    """How the simulated front end sees the world."""

    errors: SegmentationErrorConfig = field(default_factory=SegmentationErrorConfig)
    """Per-agent segmentation / caption error rates (semantic, over-, under-segmentation, drops)."""
    fusion: FusionConfig = field(default_factory=FusionConfig)
    """Cross-frame fusion (OpenObj's thresholds)."""
    alignment: AlignmentConfig = field(default_factory=AlignmentConfig)
    """Cross-agent alignment thresholds."""


@dataclass
class TeamPerception:
    """Every agent's frames, masks and fused instances (agent names ``agent_K``)."""

    frames: dict[str, list[Frame]]
    segmentations: dict[str, list[FrameSegmentation]]
    fused: dict[str, FusionResult]


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


def category_vocabulary(world: World) -> list[str]:
    """The scene's category names (what zero-shot labelling chooses from), sorted."""
    return sorted({inst.category for inst in world.scene.instances})


def structure_ids(codebook: CodeBook, labels: dict[int, str]) -> set[int]:
    """Ids whose zero-shot label is wall, floor or ceiling (they get the wider structure networks)."""
    return {i for i in codebook if labels.get(i) in STRUCTURE_CATEGORIES}


def semantic_ground_truth(world: World, n_points: int = 200_000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) points on the observable ground-truth surface and their (n,) category names."""
    points, _, ids = world.surface.sample_points(n_points, seed=seed)
    category = {inst.instance_id: inst.category for inst in world.scene.instances}
    return points, np.array([category[int(i)] for i in ids])


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


def score_semantics(gt_points: np.ndarray, gt_labels: np.ndarray, recon_points: np.ndarray, recon_ids: np.ndarray,
                    codebook: CodeBook, vocabulary: list[str], text_encoder: TextEncoder | None = None) -> SemanticMetrics:
    """F-mIoU / F-mAcc of a reconstruction whose instance ids have meanings in ``codebook``."""
    labels = zero_shot_labels(codebook, vocabulary, text_encoder or shared_text_encoder())
    return semantic_metrics(gt_points, gt_labels, recon_points, recon_ids, labels)
