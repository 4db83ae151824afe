"""An agent's frames from the simulated world as a ``mapping.team.AgentStream``: render -> segment
(the seeded error model) -> caption features, frame by frame, only when the team asks for the frame;
one stream per agent (``world_streams``) and the scene's vocabulary (``world_vocabulary``)."""

from __future__ import annotations

from collections import OrderedDict
from typing import Callable

from mapping.data import Frame
from mapping.perception import FrameSegmentation, TextEncoder, Vocabulary, shared_text_encoder
from mapping.perception.errors import SegmentationErrorConfig
from mapping.perception.front_end import encode_segments
from mapping.perception.image_encoder import ImageTextEncoder
from mapping.perception.segmenter import OracleSegmenter
from openmulti_env.world.scene import STRUCTURE_CATEGORIES
from openmulti_env.world.semantics import instance_anchor_points, instance_infos
from openmulti_env.world.world import World


class RenderCache:
    """Rendered frames of one world kept in memory up to ``max_mb``: an env renders the same paths every
    episode (only the segmentation draws change), and rendering is a third of a ``tiny`` step. Frames
    past the cap are rendered each time. Cached frames are shared: nothing downstream writes into them (the
    env's determinism test compares a cold and a warm episode)."""

    def __init__(self, world: World, max_mb: float = 256.0):
        self.world, self.max_bytes = world, max_mb * 1e6
        self._frames: dict[tuple[int, int], Frame] = {}
        self.bytes = 0

    def render(self, agent: int, index: int) -> Frame:
        key = (agent, index)
        frame = self._frames.get(key)
        if frame is None:
            frame = self.world.render(agent, index)
            size = sum(a.nbytes for a in (frame.rgb, frame.depth, frame.instance) if a is not None)
            if self.bytes + size <= self.max_bytes:
                self._frames[key], self.bytes = frame, self.bytes + size
        return frame

    def clear(self) -> None:
        """Forget every kept frame (an env whose episodes no longer render, e.g. recorded ones)."""
        self._frames, self.bytes = {}, 0


class WorldStream:
    """Agent ``agent``'s path through ``world``; the last ``cache`` frames are kept (a ray message
    re-reads the round's poses). ``render`` replaces ``world.render`` (e.g. a ``RenderCache``'s)."""

    def __init__(self, world: World, agent: int, segmenter: OracleSegmenter, text_encoder: TextEncoder,
                 image_encoder: ImageTextEncoder | None = None, cache: int = 16,
                 render: Callable[[int, int], Frame] | None = None):
        self.world, self.agent, self.segmenter = world, agent, segmenter
        self._render = render or world.render
        self.text_encoder, self.image_encoder = text_encoder, image_encoder
        self.cache = cache
        self._frames: OrderedDict[int, tuple[Frame, FrameSegmentation]] = OrderedDict()
        self.max_index_read = -1

    def __len__(self) -> int:
        return len(self.world.agent_poses[self.agent])

    def read(self, index: int) -> tuple[Frame, FrameSegmentation]:
        if not 0 <= index < len(self):
            raise IndexError(f"agent_{self.agent} has frames 0..{len(self) - 1}, not {index}")
        if index in self._frames:
            self._frames.move_to_end(index)
            return self._frames[index]
        frame = self._render(self.agent, index)
        seg = encode_segments(self.segmenter.segment(frame), frame, self.text_encoder, self.image_encoder)
        self.max_index_read = max(self.max_index_read, index)
        self._frames[index] = (frame, seg)
        while len(self._frames) > self.cache:
            self._frames.popitem(last=False)
        return frame, seg


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
