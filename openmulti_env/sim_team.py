"""A team over the simulated world: one ``WorldStream`` per agent (oracle segmenter with the seeded
error model) and the scene's vocabulary for zero-shot labels. The learner itself is ``mapping.team``."""

from __future__ import annotations

from mapping.perception import TextEncoder, shared_text_encoder
from mapping.perception.errors import SegmentationErrorConfig
from mapping.perception.image_encoder import ImageTextEncoder
from mapping.perception.segmenter import OracleSegmenter
from mapping.team import Vocabulary
from openmulti_env.world.scene import STRUCTURE_CATEGORIES
from openmulti_env.world.semantics import instance_anchor_points, instance_infos
from openmulti_env.world.world import World
from openmulti_env.world_stream import WorldStream


def world_streams(world: World, seed: int, segmentation_errors: bool = True,
                  errors: SegmentationErrorConfig | None = None, text_encoder: TextEncoder | None = None,
                  image_encoder: ImageTextEncoder | None = None, render=None) -> list[WorldStream]:
    """One stream per agent: render -> oracle segmenter (errors seeded per agent) -> caption features
    (``render``: a replacement for ``world.render``, e.g. ``RenderCache(world).render``)."""
    encoder = text_encoder or shared_text_encoder()
    config = errors or (SegmentationErrorConfig() if segmentation_errors else SegmentationErrorConfig.none())
    infos = instance_infos(world.scene)
    anchors = instance_anchor_points(world.scene, seed=seed)
    return [WorldStream(world, a, OracleSegmenter(infos, config, seed=seed, agent=a, anchor_points=anchors), encoder,
                        image_encoder, render=render) for a in range(world.num_agents)]


def world_vocabulary(world: World, text_encoder: TextEncoder | None = None) -> Vocabulary:
    """The scene's category names (sorted), walls / floor / ceiling as structure."""
    names = sorted({inst.category for inst in world.scene.instances})
    return Vocabulary.from_encoder(names, text_encoder or shared_text_encoder(), STRUCTURE_CATEGORIES)
