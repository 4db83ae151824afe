"""The simulated world: procedural indoor scenes (trimesh), observable ground truth, RGB-D rendering
with exact instance ids (pyrender), and agent camera paths."""

from openmulti_env.world.presets import REPLICA_LIKE_PRESETS, list_presets, make_scene
from openmulti_env.world.scene import Instance, Scene
from openmulti_env.world.world import World, WorldConfig

__all__ = ["Instance", "REPLICA_LIKE_PRESETS", "Scene", "World", "WorldConfig", "list_presets", "make_scene"]
