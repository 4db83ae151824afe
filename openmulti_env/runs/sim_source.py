"""The simulated world as a ``mapping.pipeline.Source``: each agent's path rendered, segmented with the
seeded error model and captioned frame by frame (``world.stream``), the scene's vocabulary, and the
observable ground truth with its free-space viewpoints."""

from __future__ import annotations

import numpy as np

from mapping.data import Frame
from mapping.perception import TextEncoder, Vocabulary
from mapping.perception.image_encoder import ImageTextEncoder
from mapping.pipeline.source import CameraViews, GroundTruth
from openmulti_env.world.semantics import category_vocabulary, semantic_ground_truth
from openmulti_env.world.stream import WorldStream, world_streams, world_vocabulary
from openmulti_env.world.world import World

SEMANTIC_POINTS = 200_000
"""Ground-truth surface samples for F-mIoU / F-mAcc."""
SENSOR_VIEW_STRIDE = 4
"""Pixel stride of the sensor-vs-map pictures."""


class SimulatedSource:
    """``world``'s agents as a run's source; ``seed`` draws the segmentation errors (with
    ``segmentation_errors=False`` the masks are perfect)."""

    def __init__(self, world: World, seed: int, text_encoder: TextEncoder,
                 image_encoder: ImageTextEncoder | None = None, segmentation_errors: bool = True):
        self.world, self.seed, self.segmentation_errors = world, seed, segmentation_errors
        self.text_encoder, self.image_encoder = text_encoder, image_encoder
        self.name = world.scene.name

    def streams(self) -> list[WorldStream]:
        return world_streams(self.world, self.seed, self.segmentation_errors, text_encoder=self.text_encoder,
                             image_encoder=self.image_encoder)

    def vocabulary(self) -> Vocabulary:
        return world_vocabulary(self.world, self.text_encoder)

    def ground_truth(self, seed: int) -> GroundTruth:
        """The surface free space can see (``World.surface``), culled the same way the maps are."""
        surface = self.world.surface
        return GroundTruth(surface.culled_mesh(), "gt_observable.ply", surface.viewpoints,
                           category_vocabulary(self.world), semantic_ground_truth(self.world, SEMANTIC_POINTS, seed),
                           "Meshes are culled to what the free-space viewpoints can see;")

    def sensor_views(self, agent: int) -> tuple[list[Frame], int]:
        """Frames a third and two thirds along the agent's path."""
        n = len(self.world.agent_poses[agent])
        return [self.world.render(agent, i) for i in (n // 3, 2 * n // 3)], SENSOR_VIEW_STRIDE

    def agent_frames(self, agent: int, every: int, offset: int = 0) -> list[Frame]:
        return [self.world.render(agent, i) for i in range(offset, len(self.world.agent_poses[agent]), max(1, every))]

    def camera_views(self, stride: int) -> CameraViews:
        """Every ``stride``-th pose of every agent's path with the depth the sensor observed there (the
        poses the agents took: the sequence NICE-SLAM culls with)."""
        poses, depths = [], []
        for agent, path in enumerate(self.world.agent_poses):
            for i in range(0, len(path), max(1, stride)):
                poses.append(np.asarray(path[i], np.float64))
                depths.append(self.world.render(agent, i).depth)
        return CameraViews(np.stack(poses), np.stack(depths), self.world.intrinsics)
