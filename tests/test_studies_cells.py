"""The studies' cells and validation worlds: how a cell and a world name their scene and seed, and that no
validation world is a test cell."""

import pytest

from studies.cells import FURNISHED_WORLDS, HEADROOM_CELLS, TEST_CELLS, VALIDATION_WORLDS, parse_cell, split_world

FRESH_CELLS = tuple(f"{scene}:{seed}" for scene in ("office3", "office4", "room2") for seed in (3, 4, 5))
"""The second set of unseen cells docs/learning.md reports (``--cells`` of ``studies.learned_vs_fixed``)."""


def test_a_cell_names_its_scene_and_world_seed():
    assert parse_cell("room1:3") == ("room1", 3)
    assert parse_cell("random:200:3") == ("random:200", 3)
    for bad in ("room1", "room1:", ":3", "room1:x"):
        with pytest.raises(ValueError, match="SCENE:WORLD_SEED"):
            parse_cell(bad)


def test_the_headroom_cells_are_test_cells():
    assert all(f"{scene}:{seed}" in TEST_CELLS for scene, seed in HEADROOM_CELLS)


def test_a_random_room_plays_at_the_episode_seed():
    assert split_world("random:200", 4) == ("random:200", None, 4)
    assert split_world("office0", 2) == ("office0", None, 2)


def test_a_furnished_cell_is_built_and_played_at_its_seed():
    assert split_world("room0:6", 0) == ("room0", 6, 6)
    assert split_world("random:200:3", 0) == ("random:200", 3, 3)


def test_no_validation_world_is_a_test_cell_or_a_test_scene():
    test_scenes = {parse_cell(cell)[0] for cell in TEST_CELLS + FRESH_CELLS}
    for world in FURNISHED_WORLDS + VALIDATION_WORLDS:
        scene, _, _ = split_world(world, 0)
        assert world not in TEST_CELLS + FRESH_CELLS
        assert scene not in test_scenes
