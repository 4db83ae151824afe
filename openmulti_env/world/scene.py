"""A scene is a list of instances, each with its own world-frame mesh and its semantic metadata.

Room coordinates: metres, x in [0, size_x], y in [0, size_y], floor at z = 0, z up. Instance id 0 is
reserved for "no instance" in instance images; real instances are numbered from 1.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

STRUCTURE_CATEGORIES = ("wall", "floor", "ceiling")
WALL_THICKNESS_M = 0.10


@dataclass
class Instance:
    """One object of the scene with its ground-truth mesh and what a captioner would say about it.

    Attributes:
        instance_id: 1-based id, unique in the scene.
        category: noun class ("chair", "wall", ...).
        caption: natural description ("a small red ceramic mug").
        color: main colour, rgb in [0, 1].
        color_name: the colour's word.
        material: material word ("wooden", "fabric", ...).
        mesh: world-frame mesh with per-face colours.
        parts: closed primitive parts (world frame) whose union is the object; used for collision.
        support_id: id of the instance it rests on (0 = floor or wall).
    """

    instance_id: int
    category: str
    caption: str
    color: tuple[float, float, float]
    color_name: str
    material: str
    mesh: trimesh.Trimesh
    parts: list[trimesh.Trimesh] = field(default_factory=list)
    support_id: int = 0

    @property
    def is_structure(self) -> bool:
        """True for walls, floor and ceiling."""
        return self.category in STRUCTURE_CATEGORIES

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) axis-aligned bounds of the mesh."""
        return np.asarray(self.mesh.bounds)

    def describe(self) -> dict:
        """JSON-ready summary: id, category, caption, colour, material."""
        return {
            "id": self.instance_id,
            "category": self.category,
            "caption": self.caption,
            "color": [round(float(c), 3) for c in self.color],
            "color_name": self.color_name,
            "material": self.material,
        }


@dataclass
class Scene:
    """A room and the instances in it."""

    name: str
    size_m: tuple[float, float, float]
    instances: list[Instance]
    seed: int | None = None

    def __post_init__(self) -> None:
        ids = [inst.instance_id for inst in self.instances]
        if len(set(ids)) != len(ids) or min(ids, default=1) < 1:
            raise ValueError(f"scene {self.name!r}: instance ids must be unique and >= 1, got {ids}")
        self._by_id = {inst.instance_id: inst for inst in self.instances}

    def instance(self, instance_id: int) -> Instance:
        """The instance with this id (KeyError naming it when absent)."""
        try:
            return self._by_id[instance_id]
        except KeyError:
            raise KeyError(f"scene {self.name!r} has no instance {instance_id}") from None

    @property
    def categories(self) -> list[str]:
        """Sorted distinct categories present."""
        return sorted({inst.category for inst in self.instances})

    def mesh(self) -> trimesh.Trimesh:
        """All instances concatenated; ``face_instance_ids()`` gives each face's instance."""
        return trimesh.util.concatenate([inst.mesh for inst in self.instances])

    def face_instance_ids(self) -> np.ndarray:
        """(n_faces,) int32 instance id of every face of ``mesh()``, in the same order."""
        return np.concatenate(
            [np.full(len(inst.mesh.faces), inst.instance_id, dtype=np.int32) for inst in self.instances]
        )

    def describe(self) -> dict:
        """JSON-ready summary of the scene."""
        return {
            "name": self.name,
            "seed": self.seed,
            "size_m": [round(float(s), 3) for s in self.size_m],
            "num_instances": len(self.instances),
            "instances": [inst.describe() for inst in self.instances],
        }

    def export(self, directory: str | Path) -> Path:
        """Write ``scene.ply``, ``instances/<id>_<category>.ply`` and ``scene.json`` under ``directory``."""
        out = Path(directory)
        (out / "instances").mkdir(parents=True, exist_ok=True)
        self.mesh().export(out / "scene.ply")
        for inst in self.instances:
            inst.mesh.export(out / "instances" / f"{inst.instance_id:03d}_{inst.category}.ply")
        (out / "scene.json").write_text(json.dumps(self.describe(), indent=2))
        return out


def colored_box(extents, center, rgb) -> trimesh.Trimesh:
    """Axis-aligned closed box with one face colour.

    Parameters
    ----------
    extents : (3,) float
      Side lengths in metres.
    center : (3,) float
      Box centre in world coordinates.
    rgb : (3,) float
      Colour in [0, 1].
    """
    box = trimesh.creation.box(extents=extents)
    box.apply_translation(center)
    box.visual.face_colors = np.append(np.clip(np.asarray(rgb) * 255, 0, 255), 255).astype(np.uint8)
    return box


STRUCTURE_PALETTE = {
    "wall": [("off-white", (0.86, 0.85, 0.80)), ("pale blue", (0.70, 0.78, 0.85)), ("beige", (0.84, 0.78, 0.66)),
             ("light grey", (0.75, 0.75, 0.75)), ("sage green", (0.68, 0.76, 0.64))],
    "floor": [("oak", (0.62, 0.48, 0.32)), ("dark wood", (0.38, 0.26, 0.18)), ("grey tile", (0.55, 0.55, 0.57)),
              ("beige carpet", (0.72, 0.66, 0.55))],
    "ceiling": [("white", (0.93, 0.93, 0.92)), ("off-white", (0.88, 0.87, 0.84))],
}
FLOOR_MATERIAL = {"oak": "wooden", "dark wood": "wooden", "grey tile": "ceramic", "beige carpet": "carpet"}


def build_structure(size_m, rng: np.random.Generator, first_id: int = 1) -> list[Instance]:
    """Floor, ceiling and four walls of a room as separate instances.

    The inner faces lie exactly on the room's box [0, sx] x [0, sy] x [0, sz]; the slabs extend
    ``WALL_THICKNESS_M`` outwards, so no structure intrudes into the free space.
    """
    sx, sy, sz = (float(s) for s in size_m)
    t = WALL_THICKNESS_M
    wall_name, wall_rgb = STRUCTURE_PALETTE["wall"][rng.integers(len(STRUCTURE_PALETTE["wall"]))]
    floor_name, floor_rgb = STRUCTURE_PALETTE["floor"][rng.integers(len(STRUCTURE_PALETTE["floor"]))]
    ceil_name, ceil_rgb = STRUCTURE_PALETTE["ceiling"][rng.integers(len(STRUCTURE_PALETTE["ceiling"]))]
    slabs = [
        ("floor", floor_name, floor_rgb, FLOOR_MATERIAL[floor_name], (sx + 2 * t, sy + 2 * t, t), (sx / 2, sy / 2, -t / 2),
         f"the {floor_name} floor"),
        ("ceiling", ceil_name, ceil_rgb, "plaster", (sx + 2 * t, sy + 2 * t, t), (sx / 2, sy / 2, sz + t / 2),
         f"the {ceil_name} ceiling"),
        ("wall", wall_name, wall_rgb, "painted", (t, sy, sz), (-t / 2, sy / 2, sz / 2), f"a {wall_name} painted wall"),
        ("wall", wall_name, wall_rgb, "painted", (t, sy, sz), (sx + t / 2, sy / 2, sz / 2), f"a {wall_name} wall"),
        ("wall", wall_name, wall_rgb, "painted", (sx + 2 * t, t, sz), (sx / 2, -t / 2, sz / 2), f"a plain {wall_name} wall"),
        ("wall", wall_name, wall_rgb, "painted", (sx + 2 * t, t, sz), (sx / 2, sy + t / 2, sz / 2), f"the {wall_name} wall"),
    ]
    out = []
    for k, (cat, cname, rgb, material, ext, ctr, caption) in enumerate(slabs):
        box = colored_box(ext, ctr, rgb)
        out.append(Instance(first_id + k, cat, caption, tuple(rgb), cname, material, box, [box.copy()]))
    return out
