"""Parametric furniture library for procedural indoor scenes.

``build_furniture(category, rng)`` returns a :class:`FurnitureModel` in its LOCAL frame:

* metres, z up; origin at the centre of the footprint's bounding box on the floor
  (``z = 0`` is the object's bottom, the x/y bounding box is centred on 0);
* the object's front faces +y (sofa seat opens to +y, screens face +y, bookshelf shelves
  open to +y, cabinet doors/handles on the +y face, bed headboard at -y);
* ``mesh`` is the concatenation of ``parts`` (all closed primitives) with per-face colours.

Placement conventions (``FurnitureModel.placement``):

* ``"floor"``        stands anywhere on the floor (chair, table, sofa...);
* ``"wall"``         stands on the floor with its back (-y side) against a wall
                     (bookshelf, cabinet, wardrobe, desk, bed, nightstand, sofa);
* ``"wall_mounted"`` a flat object hung on a wall (door, window_frame, picture).  Its back is at
                     local ``y = -size_y / 2``: put that plane on the wall surface with +y pointing
                     into the room and lift the object by ``mount_height_m`` (height of the
                     object's bottom above the floor: 0 for doors, ~0.8-1.0 for windows,
                     ~1.0-1.45 for pictures, whose centre is then at ~1.45-1.65);
* ``"on_surface"``   small objects (``is_small``) to put on a :class:`SupportSurface`.

Lamps and plants exist in two categories: ``"lamp"`` / ``"plant"`` are floor-standing,
``"table_lamp"`` / ``"potted_plant"`` are small ``on_surface`` objects.  ``"tv"`` is a flat
screen standing on a low TV stand (one object, placement "floor" as specified by the lead; its
supports are the free parts of the stand top and the open stand shelf if any).  Books stand
upright with the spine to +y (as on a shelf); pillows lie flat.  Beds do not contain pillows:
``soft_supports`` gives the free mattress area at the head end (and the seat of sofas and
armchairs) for placing ``pillow`` objects; ordinary ``supports`` never include soft surfaces.

``size_scale`` scales the finished object uniformly about its origin (supports too, but not
``mount_height_m``).

The builders live in one module per family, beside the helpers they share:

* ``base``          the dataclasses (:class:`FurnitureModel`, :class:`SupportSurface`, the builders'
                    ``FurnitureSpec``) and the helpers of more than one family (legs, door and drawer fronts,
                    cabinet carcass, support rectangles);
* ``seating``       chair, stool, sofa, armchair;
* ``tables``        table, coffee table, desk;
* ``storage``       cabinet, nightstand, wardrobe, bookshelf;
* ``beds``          bed;
* ``lighting``      lamp, table lamp;
* ``plants``        plant, potted plant;
* ``electronics``   monitor, tv (with its stand), keyboard, laptop;
* ``small_objects`` mug, bottle, book, pillow, vase, trash bin, box;
* ``fixtures``      rug, door, window frame, picture.

This module holds the category -> builder table and :func:`build_furniture`, which centres and scales
what a builder returns.  Primitives, colours and captions are in :mod:`openmulti_env.world.furniture_parts`.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from openmulti_env.world.furniture.base import MARGIN, FurnitureModel, SupportSurface, FurnitureSpec
from openmulti_env.world.furniture.beds import build_bed
from openmulti_env.world.furniture.electronics import build_keyboard, build_laptop, build_monitor, build_tv
from openmulti_env.world.furniture.fixtures import build_door, build_picture, build_rug, build_window_frame
from openmulti_env.world.furniture.lighting import build_lamp, build_table_lamp
from openmulti_env.world.furniture.plants import build_plant, build_potted_plant
from openmulti_env.world.furniture.seating import build_armchair, build_chair, build_sofa, build_stool
from openmulti_env.world.furniture.small_objects import build_book, build_bottle, build_box, build_mug, build_pillow, build_trash_bin, build_vase
from openmulti_env.world.furniture.storage import build_bookshelf, build_cabinet, build_nightstand, build_wardrobe
from openmulti_env.world.furniture.tables import build_coffee_table, build_desk, build_table
from openmulti_env.world.furniture_parts import concat

__all__ = ["CATEGORIES", "MARGIN", "SMALL_CATEGORIES", "FurnitureModel", "SupportSurface", "build_furniture"]

_BUILDERS: dict[str, Callable[[np.random.Generator], FurnitureSpec]] = {
    "chair": build_chair, "armchair": build_armchair, "sofa": build_sofa, "stool": build_stool,
    "table": build_table, "coffee_table": build_coffee_table, "desk": build_desk,
    "bed": build_bed, "nightstand": build_nightstand, "cabinet": build_cabinet, "wardrobe": build_wardrobe, "bookshelf": build_bookshelf,
    "lamp": build_lamp, "plant": build_plant, "tv": build_tv, "rug": build_rug, "trash_bin": build_trash_bin, "box": build_box,
    "door": build_door, "window_frame": build_window_frame, "picture": build_picture,
    "table_lamp": build_table_lamp, "potted_plant": build_potted_plant, "monitor": build_monitor, "keyboard": build_keyboard,
    "laptop": build_laptop, "mug": build_mug, "bottle": build_bottle, "book": build_book, "pillow": build_pillow, "vase": build_vase,
}

_PLACEMENT: dict[str, str] = {
    "chair": "floor", "armchair": "floor", "sofa": "wall", "stool": "floor", "table": "floor",
    "coffee_table": "floor", "desk": "wall", "bed": "wall", "nightstand": "wall", "cabinet": "wall",
    "wardrobe": "wall", "bookshelf": "wall", "lamp": "floor", "plant": "floor", "tv": "floor", "rug": "floor",
    "trash_bin": "floor", "box": "floor", "door": "wall_mounted", "window_frame": "wall_mounted",
    "picture": "wall_mounted",
}

CATEGORIES: tuple[str, ...] = tuple(_BUILDERS)
SMALL_CATEGORIES: tuple[str, ...] = tuple(c for c in CATEGORIES if c not in _PLACEMENT)


def _move_support(s: SupportSurface, shift: np.ndarray, scale: float) -> SupportSurface:
    return SupportSurface(float((s.height_m + shift[2]) * scale),
                          (float(s.half_extent_xy[0] * scale), float(s.half_extent_xy[1] * scale)),
                          (float((s.center_xy[0] + shift[0]) * scale), float((s.center_xy[1] + shift[1]) * scale)),
                          float(s.clearance_m * scale))


def build_furniture(category: str, rng: np.random.Generator, size_scale: float = 1.0) -> FurnitureModel:
    """Build a randomised instance of ``category`` (see :data:`CATEGORIES`) in its local frame."""
    if category not in _BUILDERS:
        raise ValueError(f"unknown furniture category {category!r}; known categories: {', '.join(CATEGORIES)}")
    spec = _BUILDERS[category](rng)
    parts = [p for p in spec.parts]
    mesh = concat(parts)
    lo, hi = mesh.bounds
    shift = np.array([-(lo[0] + hi[0]) / 2.0, -(lo[1] + hi[1]) / 2.0, -lo[2]])
    s = float(size_scale)
    for p in parts:
        p.apply_translation(shift)
        if s != 1.0:
            p.apply_scale(s)
    mesh.apply_translation(shift)
    if s != 1.0:
        mesh.apply_scale(s)
    mesh.metadata["category"] = category
    placement = _PLACEMENT.get(category, "on_surface")
    return FurnitureModel(
        category=category, mesh=mesh, parts=parts, color=tuple(float(c) for c in spec.color),
        color_name=spec.color_name, material=spec.material, caption=spec.caption,
        size_m=tuple(float(e) for e in mesh.extents),
        supports=[_move_support(x, shift, s) for x in spec.supports], placement=placement,
        is_small=placement == "on_surface", mount_height_m=float(spec.mount_height_m),
        soft_supports=[_move_support(x, shift, s) for x in spec.soft_supports], variant=spec.variant)
