"""The shipping rule's validation worlds: how a world names its scene and seed, and that none is a test cell."""

from benchmarks.learned_vs_fixed import CELLS
from benchmarks.pick_on_validation import FURNISHED, WORLDS, split_world

FRESH_CELLS = tuple(f"{scene}:{seed}" for scene in ("office3", "office4", "room2") for seed in (3, 4, 5))
"""The second set of unseen cells docs/learning.md reports (``--cells`` of ``learned_vs_fixed.py``)."""


def test_a_random_room_plays_at_the_episode_seed():
    assert split_world("random:200", 4) == ("random:200", None, 4)
    assert split_world("office0", 2) == ("office0", None, 2)


def test_a_furnished_cell_is_built_and_played_at_its_seed():
    assert split_world("room0:6", 0) == ("room0", 6, 6)
    assert split_world("random:200:3", 0) == ("random:200", 3, 3)


def test_no_validation_world_is_a_test_cell_or_a_test_scene():
    test_scenes = {cell.split(":")[0] for cell in CELLS + FRESH_CELLS}
    for world in FURNISHED + WORLDS:
        scene, _, _ = split_world(world, 0)
        assert world not in CELLS + FRESH_CELLS
        assert scene not in test_scenes
