"""The scene-seed cells and validation worlds the studies play, in one place, so that no choice is made on a
cell that reports a result.

A cell is a furnished preset scene built and played at one world seed, written ``SCENE:SEED``. Training walks
``random:SEED`` rooms (``random:100``-``115``); settings were chosen on room0 seed 0; validation worlds pick the
policy to ship; the test cells only report.
"""

from __future__ import annotations

TEST_CELLS = ("room1:3", "room1:4", "room1:5", "office1:3", "office1:4", "office1:5", "office2:3", "office2:4",
              "office2:5")
"""Where learned schedules are judged against the fronts (3 scenes x 3 seeds no training run used)."""
HEADROOM_CELLS = (("room1", 3), ("office1", 4), ("office2", 5))
"""The headroom study's cells, never used for a choice, shared by the transfer check and the hindsight bound
(their `fast` runs are the headroom's)."""
VALIDATION_WORLDS = ("random:200", "random:201", "random:202")
"""Rooms like the training ones that no run trained on (training walked ``random:100``-``107``)."""
FURNISHED_WORLDS = ("room0:6", "room0:7", "room0:8", "office0:6", "office0:7", "office0:8")
"""Furnished validation worlds like the test cells (the two preset scenes no test cell uses), at seeds no test
cell uses."""


def parse_cell(cell: str) -> tuple[str, int]:
    """``"room1:3"`` -> ``("room1", 3)``: the scene and the world seed it is built and played at."""
    scene, sep, seed = cell.rpartition(":")
    if not (sep and scene and seed.isdigit()):
        raise ValueError(f"cell {cell!r}: expected SCENE:WORLD_SEED, e.g. room1:3")
    return scene, int(seed)


def split_world(world: str, episode_seed: int) -> tuple[str, int | None, int]:
    """A validation world's (scene, world seed, episode seed): ``"room0:6"`` -> ``("room0", 6, 6)``, a preset scene
    built and played at its seed; ``"random:200"`` -> ``("random:200", None, episode_seed)``, a random room (its
    seed is part of its name) played at the episode seed."""
    head, sep, tail = world.rpartition(":")
    if sep and head and head != "random" and tail.isdigit():
        return head, int(tail), int(tail)
    return world, None, episode_seed
