"""Procedural room layouts: furniture against walls, free-standing groups, wall-mounted items and
small objects on support surfaces, with no interpenetration.

Large objects are placed on a floor plan as axis-aligned footprints (yaw in multiples of 90 degrees)
that keep a gap between them; small objects are dropped onto support surfaces (table tops, shelves,
beds) and checked part by part against everything around them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from openmulti_env.world.collision import boxes_overlap, instances_penetrate
from openmulti_env.world.furniture import FurnitureModel, build_furniture
from mapping.evaluate.raycast import MeshRaycaster
from openmulti_env.world.scene import Instance, Scene, build_structure

FLOOR_GAP_M = 0.06  # free gap kept between footprints of floor objects
WALL_GAP_M = 0.02  # gap between a wall-standing object and its wall
SMALL_LIFT_M = 1e-3  # small objects rest this far above their support (an exact contact is ambiguous)
# Wall index -> (yaw that makes local +y point into the room, description). Walls: 0: y=0, 1: x=sx, 2: y=sy, 3: x=0.
WALL_YAW_DEG = {0: 0.0, 1: 90.0, 2: 180.0, 3: -90.0}


@dataclass
class RoomRecipe:
    """What a kind of room contains; counts are (min, max) inclusive."""

    kind: str
    size_m: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    wall_items: dict[str, tuple[int, int]] = field(default_factory=dict)
    free_items: dict[str, tuple[int, int]] = field(default_factory=dict)
    dining_sets: tuple[int, int] = (0, 0)
    wall_mounted: dict[str, tuple[int, int]] = field(default_factory=dict)
    small_items: tuple[str, ...] = ("book", "mug", "bottle", "vase")
    small_per_surface: tuple[int, int] = (1, 3)
    pillows_on: tuple[str, ...] = ("bed", "sofa")


@dataclass
class _Placed:
    instance: Instance
    model: FurnitureModel
    transform: np.ndarray  # local -> world 4x4
    footprint: np.ndarray | None  # (2, 2) xy box incl. nothing else; None for wall-mounted/small


def _transform(yaw_deg: float, xyz) -> np.ndarray:
    t = trimesh.transformations.rotation_matrix(np.radians(yaw_deg), [0, 0, 1])
    t[:3, 3] = xyz
    return t


class LayoutBuilder:
    """Places furniture into one room; ``build()`` returns the finished Scene."""

    def __init__(self, name: str, recipe: RoomRecipe, rng: np.random.Generator, seed: int | None = None):
        self.name, self.recipe, self.rng, self.seed = name, recipe, rng, seed
        self.size = tuple(float(rng.uniform(lo, hi)) for lo, hi in recipe.size_m)
        self.instances: list[Instance] = build_structure(self.size, rng)
        self.placed: list[_Placed] = []
        self.reserved: list[np.ndarray] = []  # floor areas kept free (in front of doors)

    # ----- helpers -----------------------------------------------------------------------------
    def _next_id(self) -> int:
        return max(inst.instance_id for inst in self.instances) + 1

    def _add(self, model: FurnitureModel, transform: np.ndarray, footprint, support_id: int = 0) -> Instance:
        mesh = model.mesh.copy()
        mesh.apply_transform(transform)
        parts = [p.copy().apply_transform(transform) for p in model.parts]
        inst = Instance(self._next_id(), model.category, model.caption, tuple(model.color), model.color_name,
                        model.material, mesh, parts, support_id)
        self.instances.append(inst)
        self.placed.append(_Placed(inst, model, transform, footprint))
        return inst

    def _footprint_free(self, fp: np.ndarray) -> bool:
        sx, sy, _ = self.size
        if fp[0, 0] < -1e-9 or fp[0, 1] < -1e-9 or fp[1, 0] > sx + 1e-9 or fp[1, 1] > sy + 1e-9:
            return False
        grown = fp + np.array([[-FLOOR_GAP_M] * 2, [FLOOR_GAP_M] * 2])
        others = [p.footprint for p in self.placed if p.footprint is not None] + self.reserved
        return not any(_rects_overlap(grown, o) for o in others)

    @staticmethod
    def _rotated_half_extents(model: FurnitureModel, yaw_deg: float) -> np.ndarray:
        hx, hy = model.size_m[0] / 2, model.size_m[1] / 2
        return np.array([hy, hx]) if int(round(yaw_deg)) % 180 else np.array([hx, hy])

    # ----- floor objects -----------------------------------------------------------------------
    def place_against_wall(self, model: FurnitureModel, tries: int = 80) -> Instance | None:
        """Back of the object to a random wall, front into the room."""
        sx, sy, _ = self.size
        for _ in range(tries):
            wall = int(self.rng.integers(4))
            yaw = WALL_YAW_DEG[wall]
            h = self._rotated_half_extents(model, yaw)
            depth = model.size_m[1] / 2 + WALL_GAP_M
            if wall in (0, 2):
                if sx - 2 * h[0] < 0:
                    continue
                x = self.rng.uniform(h[0], sx - h[0])
                y = depth if wall == 0 else sy - depth
            else:
                if sy - 2 * h[1] < 0:
                    continue
                y = self.rng.uniform(h[1], sy - h[1])
                x = depth if wall == 3 else sx - depth
            fp = np.array([[x - h[0], y - h[1]], [x + h[0], y + h[1]]])
            if self._footprint_free(fp):
                return self._add(model, _transform(yaw, (x, y, 0.0)), fp)
        return None

    def place_free(self, model: FurnitureModel, margin_m: float = 0.5, tries: int = 80) -> Instance | None:
        """Anywhere on the floor at least ``margin_m`` from the walls (room to walk around it)."""
        sx, sy, _ = self.size
        for _ in range(tries):
            yaw = float(self.rng.choice([0.0, 90.0, 180.0, -90.0]))
            h = self._rotated_half_extents(model, yaw)
            lo, hi = h + margin_m, np.array([sx, sy]) - h - margin_m
            if np.any(hi < lo):
                return None
            x, y = self.rng.uniform(lo, hi)
            fp = np.array([[x - h[0], y - h[1]], [x + h[0], y + h[1]]])
            if self._footprint_free(fp):
                return self._add(model, _transform(yaw, (x, y, 0.0)), fp)
        return None

    def place_dining_set(self, table: FurnitureModel, chairs: list[FurnitureModel]) -> None:
        """A table away from the walls and chairs on its sides, facing it."""
        t = self.place_free(table, margin_m=0.8)
        if t is None:
            return
        fp = self.placed[-1].footprint
        cx, cy = fp.mean(axis=0)
        sides = [(0.0, -1), (180.0, 1), (-90.0, -2), (90.0, 2)]  # yaw, which side (+-1: y, +-2: x)
        for chair, (yaw, side) in zip(chairs, sides):
            h = self._rotated_half_extents(chair, yaw)
            if abs(side) == 1:
                x, y = cx, (fp[0, 1] - h[1] - 0.08) if side < 0 else (fp[1, 1] + h[1] + 0.08)
            else:
                x, y = (fp[0, 0] - h[0] - 0.08) if side < 0 else (fp[1, 0] + h[0] + 0.08), cy
            cfp = np.array([[x - h[0], y - h[1]], [x + h[0], y + h[1]]])
            # chairs tuck close to the table: check against everything but their own table
            others = [p.footprint for p in self.placed if p.footprint is not None and p.instance is not t]
            grown = cfp + np.array([[-FLOOR_GAP_M] * 2, [FLOOR_GAP_M] * 2])
            sx, sy, _ = self.size
            inside = cfp[0, 0] >= 0 and cfp[0, 1] >= 0 and cfp[1, 0] <= sx and cfp[1, 1] <= sy
            if inside and not any(_rects_overlap(grown, o) for o in others + self.reserved):
                self._add(chair, _transform(yaw, (x, y, 0.0)), cfp)

    # ----- wall-mounted --------------------------------------------------------------------------
    def place_on_wall(self, model: FurnitureModel, tries: int = 60) -> Instance | None:
        """A flat item (door, window, picture) with its back on a wall at its mount height."""
        sx, sy, sz = self.size
        z0 = float(getattr(model, "mount_height_m", 0.0))
        if z0 + model.size_m[2] > sz - 0.05:
            z0 = max(0.0, sz - 0.05 - model.size_m[2])
        for _ in range(tries):
            wall = int(self.rng.integers(4))
            yaw = WALL_YAW_DEG[wall]
            h = self._rotated_half_extents(model, yaw)
            depth = model.size_m[1] / 2 + 1e-3
            if wall in (0, 2):
                if sx - 2 * h[0] - 0.2 < 0:
                    continue
                x = self.rng.uniform(h[0] + 0.1, sx - h[0] - 0.1)
                y = depth if wall == 0 else sy - depth
            else:
                if sy - 2 * h[1] - 0.2 < 0:
                    continue
                y = self.rng.uniform(h[1] + 0.1, sy - h[1] - 0.1)
                x = depth if wall == 3 else sx - depth
            tf = _transform(yaw, (x, y, z0))
            box = trimesh.transform_points(np.array(model.mesh.bounds), tf)
            box = np.array([box.min(axis=0), box.max(axis=0)])
            grown = box + np.array([[-0.05, -0.05, -0.05], [0.05, 0.05, 0.05]])
            if any(boxes_overlap(grown, p.instance.bounds) for p in self.placed):
                continue
            if model.category == "door":
                # keep the floor in front of a door free
                reach = 0.9
                fp = box[:, :2].copy()
                if wall == 0:
                    fp[1, 1] += reach
                elif wall == 2:
                    fp[0, 1] -= reach
                elif wall == 3:
                    fp[1, 0] += reach
                else:
                    fp[0, 0] -= reach
                if not self._footprint_free(fp):
                    continue
                self.reserved.append(fp)
            return self._add(model, tf, None)
        return None

    # ----- small objects -----------------------------------------------------------------------
    def place_small_on(self, host: _Placed, categories: tuple[str, ...], count: int) -> None:
        """Drop ``count`` small objects onto the host's support surfaces (a few tries each)."""
        for surface in host.model.supports:
            for _ in range(count):
                cat = str(self.rng.choice(categories))
                model = build_furniture(cat, self.rng)
                if model.size_m[2] > surface.clearance_m - 0.02:
                    continue
                for _try in range(15):
                    yaw = float(self.rng.uniform(-180, 180))
                    r = 0.5 * np.hypot(model.size_m[0], model.size_m[1])
                    hx, hy = surface.half_extent_xy
                    if hx < r or hy < r:
                        break
                    lx = surface.center_xy[0] + self.rng.uniform(-hx + r, hx - r)
                    ly = surface.center_xy[1] + self.rng.uniform(-hy + r, hy - r)
                    local = np.array([lx, ly, surface.height_m + SMALL_LIFT_M, 1.0])
                    world = host.transform @ local
                    if self._try_small(model, yaw, world[:3], host):
                        break

    def place_pillows(self, host: _Placed, count: int) -> None:
        """Pillows dropped onto a bed's or sofa's top near its back, found by casting rays down."""
        caster = MeshRaycaster(host.instance.mesh)
        sx_, sy_, _ = host.model.size_m
        yaw = float(np.degrees(np.arctan2(host.transform[1, 0], host.transform[0, 0])))
        for k in range(count):
            model = build_furniture("pillow", self.rng)
            lx = (k - (count - 1) / 2) * min(model.size_m[0] + 0.08, sx_ / max(count, 1))
            for ly in np.linspace(-sy_ / 2 + model.size_m[1] / 2 + 0.12, 0.0, 5):
                centre = host.transform @ np.array([lx, ly, 0.0, 1.0])
                z = self._drop_height(caster, model, yaw, centre[:3])
                if z is not None and self._try_small(model, yaw, np.array([centre[0], centre[1], z + SMALL_LIFT_M]), host):
                    break

    @staticmethod
    def _drop_height(caster: MeshRaycaster, model: FurnitureModel, yaw: float, centre: np.ndarray) -> float | None:
        hx, hy = model.size_m[0] / 2, model.size_m[1] / 2
        corners = np.array([[a * hx, b * hy, 0.0] for a in (-1, 0, 1) for b in (-1, 0, 1)])
        pts = trimesh.transform_points(corners, _transform(yaw, centre))
        pts[:, 2] = 5.0
        t, _ = caster.cast(pts, np.tile([0.0, 0.0, -1.0], (len(pts), 1)))
        if not np.all(np.isfinite(t)):
            return None
        return float(np.max(5.0 - t))

    def _try_small(self, model: FurnitureModel, yaw: float, position: np.ndarray, host: _Placed) -> bool:
        tf = _transform(yaw, position)
        mesh = model.mesh.copy().apply_transform(tf)
        parts = [p.copy().apply_transform(tf) for p in model.parts]
        probe = Instance(10**6, model.category, "", (0, 0, 0), "", "", mesh, parts)
        sx, sy, sz = self.size
        if np.any(mesh.bounds[0] < 0) or np.any(mesh.bounds[1] > [sx, sy, sz]):
            return False
        for other in self.instances:
            if not other.is_structure and instances_penetrate(probe, other):
                return False
        self._add(model, tf, None, support_id=host.instance.instance_id)
        return True

    # ----- the whole room ------------------------------------------------------------------------
    def build(self) -> Scene:
        r, rng = self.recipe, self.rng

        def count(lo_hi):
            return int(rng.integers(lo_hi[0], lo_hi[1] + 1))

        if "door" in r.wall_mounted:
            for _ in range(count(r.wall_mounted["door"])):
                self.place_on_wall(build_furniture("door", rng))
        for cat, n in r.wall_items.items():
            for _ in range(count(n)):
                self.place_against_wall(build_furniture(cat, rng))
        for _ in range(count(r.dining_sets)):
            table = build_furniture("table", rng)
            chair = build_furniture("chair", rng)  # one style per set, as in real rooms
            n_chairs = int(rng.integers(2, 5))
            self.place_dining_set(table, [chair] * n_chairs)
        for cat, n in r.free_items.items():
            for _ in range(count(n)):
                self.place_free(build_furniture(cat, rng), margin_m=0.35)
        for cat, n in r.wall_mounted.items():
            if cat != "door":
                for _ in range(count(n)):
                    self.place_on_wall(build_furniture(cat, rng))
        for host in list(self.placed):
            if host.model.category in r.pillows_on:
                self.place_pillows(host, 2 if host.model.category == "bed" else int(rng.integers(1, 3)))
            elif host.model.supports and r.small_items:
                self.place_small_on(host, r.small_items, count(r.small_per_surface))
        return Scene(self.name, self.size, self.instances, self.seed)


def _rects_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.all(np.minimum(a[1], b[1]) - np.maximum(a[0], b[0]) > 0))
