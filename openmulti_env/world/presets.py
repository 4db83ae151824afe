"""Named scenes that mimic the paper's Replica rooms and offices, random rooms, and user manifests.

``make_scene(name, seed)`` is the single entry point: a preset name (``room0`` ...), ``random:SEED``,
or the path of a JSON/YAML manifest. A preset with the same seed is the same room on every machine;
``seed`` varies the layout of a preset while keeping its kind of room (seed 0 is the canonical one).
"""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np

from openmulti_env.world.layout import LayoutBuilder, RoomRecipe
from openmulti_env.world.scene import Scene

DESK_SMALL = ("monitor", "keyboard", "laptop", "mug", "book", "bottle", "table_lamp", "potted_plant")
HOME_SMALL = ("book", "mug", "bottle", "vase", "potted_plant", "table_lamp")

RECIPES: dict[str, RoomRecipe] = {
    "living": RoomRecipe(
        "living", ((5.5, 6.5), (4.5, 5.2), (2.6, 2.8)),
        wall_items={"sofa": (1, 1), "bookshelf": (1, 1), "cabinet": (1, 1), "tv": (1, 1), "plant": (1, 1), "lamp": (1, 1)},
        free_items={"coffee_table": (1, 1), "armchair": (1, 1), "rug": (0, 1)},
        wall_mounted={"door": (1, 1), "window_frame": (1, 2), "picture": (1, 2)},
        small_items=HOME_SMALL, small_per_surface=(1, 3),
    ),
    "bedroom": RoomRecipe(
        "bedroom", ((4.8, 5.6), (4.2, 5.0), (2.6, 2.8)),
        wall_items={"bed": (1, 1), "nightstand": (1, 2), "wardrobe": (1, 1), "desk": (1, 1), "lamp": (0, 1), "trash_bin": (1, 1)},
        free_items={"chair": (1, 1), "rug": (0, 1)},
        wall_mounted={"door": (1, 1), "window_frame": (1, 1), "picture": (1, 2)},
        small_items=HOME_SMALL, small_per_surface=(1, 3),
    ),
    "dining": RoomRecipe(
        "dining", ((5.8, 6.8), (4.8, 5.6), (2.6, 2.9)),
        wall_items={"cabinet": (1, 2), "bookshelf": (1, 1), "sofa": (1, 1), "plant": (1, 2), "stool": (0, 1)},
        dining_sets=(1, 1),
        wall_mounted={"door": (1, 1), "window_frame": (1, 2), "picture": (1, 2)},
        small_items=HOME_SMALL, small_per_surface=(1, 3),
    ),
    "office": RoomRecipe(
        "office", ((5.0, 6.5), (4.2, 5.2), (2.6, 2.9)),
        wall_items={"desk": (2, 3), "bookshelf": (1, 1), "cabinet": (1, 1), "plant": (1, 1), "trash_bin": (1, 1)},
        free_items={"chair": (2, 3)},
        wall_mounted={"door": (1, 1), "window_frame": (1, 2), "picture": (0, 1)},
        small_items=DESK_SMALL, small_per_surface=(1, 3),
    ),
    "meeting": RoomRecipe(
        "meeting", ((6.0, 7.0), (5.0, 5.8), (2.7, 2.9)),
        wall_items={"tv": (1, 1), "cabinet": (1, 1), "plant": (1, 2), "bookshelf": (0, 1), "trash_bin": (0, 1)},
        dining_sets=(1, 1),
        wall_mounted={"door": (1, 1), "window_frame": (1, 2), "picture": (1, 1)},
        small_items=DESK_SMALL, small_per_surface=(1, 3),
    ),
    "lounge": RoomRecipe(
        "lounge", ((5.5, 6.5), (4.8, 5.6), (2.6, 2.8)),
        wall_items={"sofa": (1, 2), "bookshelf": (1, 1), "desk": (1, 1), "plant": (1, 1), "lamp": (1, 1)},
        free_items={"coffee_table": (1, 1), "armchair": (0, 1), "chair": (1, 1), "stool": (0, 1)},
        wall_mounted={"door": (1, 1), "window_frame": (1, 1), "picture": (1, 2)},
        small_items=HOME_SMALL + ("laptop",), small_per_surface=(1, 3),
    ),
    "tiny": RoomRecipe(
        "tiny", ((3.0, 3.2), (2.8, 3.0), (2.4, 2.5)),
        wall_items={"table": (1, 1), "cabinet": (1, 1)},
        free_items={"chair": (1, 1)},
        wall_mounted={"picture": (1, 1)},
        small_items=("mug", "book"), small_per_surface=(1, 2),
    ),
}

# Presets after the paper's Replica scenes (room0-2, office0-4), plus a small room for tests.
PRESETS: dict[str, str] = {
    "room0": "living",
    "room1": "bedroom",
    "room2": "dining",
    "office0": "office",
    "office1": "meeting",
    "office2": "lounge",
    "office3": "office",
    "office4": "meeting",
    "tiny": "tiny",
}
REPLICA_LIKE_PRESETS = tuple(name for name in PRESETS if name != "tiny")
RANDOM_PREFIX = "random:"


def list_presets() -> list[str]:
    """Preset names, in the paper's order."""
    return list(PRESETS)


def _stable_seed(name: str, seed: int) -> int:
    return (zlib.crc32(name.encode()) + 1_000_003 * int(seed)) % (2**32)


def make_scene(name: str = "room0", seed: int | None = 0) -> Scene:
    """Build a scene by preset name, ``random:SEED`` or manifest path.

    Args:
        name: ``room0`` ... (see ``list_presets()``), ``random:SEED`` (a random kind of room and layout),
            or a path to a ``.json``/``.yaml``/``.yml`` manifest of user meshes.
        seed: varies a preset's layout (0 = canonical); ignored for manifests.

    Raises:
        ValueError: unknown name, with the known ones listed.
    """
    seed = 0 if seed is None else int(seed)
    if name in PRESETS:
        rng = np.random.default_rng(_stable_seed(name, seed))
        return LayoutBuilder(name, RECIPES[PRESETS[name]], rng, seed).build()
    if name.startswith(RANDOM_PREFIX):
        try:
            rseed = int(name[len(RANDOM_PREFIX):])
        except ValueError:
            raise ValueError(f"scene {name!r}: expected random:<integer seed>") from None
        rng = np.random.default_rng(_stable_seed(RANDOM_PREFIX, rseed))
        kinds = [k for k in RECIPES if k != "tiny"]
        kind = kinds[int(rng.integers(len(kinds)))]
        return LayoutBuilder(name, RECIPES[kind], rng, rseed).build()
    if Path(name).suffix.lower() in (".json", ".yaml", ".yml"):
        from openmulti_env.world.manifest import load_manifest_scene  # noqa: PLC0415

        return load_manifest_scene(name)
    raise ValueError(
        f"unknown scene {name!r}: use a preset ({', '.join(PRESETS)}), 'random:SEED', or a .json/.yaml manifest path"
    )
