"""Scenes from the user's own meshes, described by a JSON or YAML manifest (format in DESIGN.md):

    {"name": "my_room", "room": {"size_m": [6.0, 5.0, 2.7]}, "up_axis": "y",
     "objects": [{"mesh": "meshes/chair.obj", "category": "chair", "caption": "a wooden chair",
                  "position_m": [1.2, 0.8], "yaw_deg": 90, "height_m": 0.9, "color": [0.6, 0.4, 0.2]}]}

Real meshes are messy: arbitrary units and axes, not watertight, few faces. Units are fixed by
``height_m`` (uniform rescale), axes by ``up_axis``; overlap between objects is judged on their
surfaces (not on a closed volume), so open meshes work, and overlapping placements are refused with
the two objects named.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from mapping.safe_parse import ParseError, load_data
from openmulti_env.world.scene import Instance, Scene, build_structure

OVERLAP_VOXEL_M = 0.01  # surfaces that share voxels of this size are in contact or crossing
RESTING_BAND_M = 0.015  # shared voxels this close to the upper object's bottom are resting contact
MAX_SHARED_VOXELS = 20  # more shared voxels than this, away from resting contact, is an overlap
ROOM_TOLERANCE_M = 0.01  # how far an object may poke out of the room box (mesh noise)
UP_AXES = {"x", "y", "z", "-x", "-y", "-z"}


class ManifestError(ValueError):
    """A scene manifest or one of its meshes is unusable; the message names the file and field."""


def _read_manifest(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise ManifestError(f"{path}: scene manifest not found")
    try:
        data = load_data(path)  # bounded in size and nesting, no duplicated keys
    except ParseError as exc:  # its message begins with the file
        raise ManifestError(f"cannot parse manifest {exc}") from None
    except OSError as exc:
        raise ManifestError(f"{path}: cannot read manifest: {exc}") from None
    if not isinstance(data, dict):
        raise ManifestError(f"{path}: manifest must be a mapping with 'room' and 'objects'")
    return data


def _vector(value: Any, length: tuple[int, ...], where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ManifestError(f"{where}: expected a list of numbers, got {value!r}") from None
    if arr.ndim != 1 or len(arr) not in length or not np.all(np.isfinite(arr)):
        raise ManifestError(f"{where}: expected {' or '.join(map(str, length))} finite numbers, got {value!r}")
    return arr


def _number(obj: dict, key: str, where: str, default: float | None = None, positive: bool = False) -> float:
    """``obj[key]`` if it is a finite number (positive: above 0); ManifestError naming the field otherwise."""
    value = obj.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) \
            or (positive and value <= 0):
        raise ManifestError(f"{where}.{key}: expected a {'positive' if positive else 'finite'} number, got {value!r}")
    return float(value)


def _text(obj: dict, key: str, where: str, default: str | None = None) -> str:
    """``obj[key]`` if it is a non-empty string; ManifestError naming the field otherwise."""
    value = obj.get(key, default)
    if not isinstance(value, str) or not value.strip():
        raise ManifestError(f"{where}.{key}: expected a non-empty string, got {value!r}")
    return value


def up_axis_rotation(up_axis: str) -> np.ndarray:
    """(4, 4) rotation taking the mesh files' ``up_axis`` to +z."""
    if up_axis not in UP_AXES:
        raise ManifestError(f"up_axis must be one of {sorted(UP_AXES)}, got {up_axis!r}")
    src = {"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1]}[up_axis[-1]]
    src = -np.asarray(src, float) if up_axis.startswith("-") else np.asarray(src, float)
    if np.allclose(src, [0, 0, -1]):
        return trimesh.transformations.rotation_matrix(np.pi, [1, 0, 0])
    return trimesh.geometry.align_vectors(src, [0.0, 0.0, 1.0])


def _load_mesh(path: Path, where: str) -> trimesh.Trimesh:
    if not path.is_file():
        raise ManifestError(f"{where}: mesh file not found: {path}")
    try:
        mesh = trimesh.load(path, force="mesh", process=True)
    except Exception as exc:  # noqa: BLE001  (trimesh raises many types for bad files)
        raise ManifestError(f"{where}: cannot read mesh {path}: {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ManifestError(f"{where}: mesh {path} has no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise ManifestError(f"{where}: mesh {path} has non-finite vertices")
    return mesh


def _face_colors(mesh: trimesh.Trimesh, color: np.ndarray | None) -> tuple[float, float, float]:
    if color is not None:
        rgba = np.append(np.clip(color, 0, 1) * 255, 255).astype(np.uint8)
        mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=np.tile(rgba, (len(mesh.faces), 1)))
        return tuple(float(c) for c in np.clip(color, 0, 1))
    try:
        fc = np.asarray(mesh.visual.to_color().face_colors)
    except Exception:  # noqa: BLE001  (textures without images and other odd visuals)
        fc = np.tile([160, 160, 160, 255], (len(mesh.faces), 1)).astype(np.uint8)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=fc)
    mean = fc[:, :3].mean(axis=0) / 255.0
    return tuple(float(c) for c in mean)


def _surface_voxels(mesh: trimesh.Trimesh, box: np.ndarray) -> set[tuple[int, int, int]]:
    count = int(min(400_000, max(2_000, mesh.area / OVERLAP_VOXEL_M**2 * 2)))
    pts, _ = trimesh.sample.sample_surface(mesh, count, seed=0)
    pts = np.concatenate([pts, mesh.vertices])
    pts = pts[np.all((pts >= box[0]) & (pts <= box[1]), axis=1)]
    return set(map(tuple, np.floor(pts / OVERLAP_VOXEL_M).astype(np.int64)))


def surfaces_overlap(a: trimesh.Trimesh, b: trimesh.Trimesh) -> bool:
    """Whether two (possibly open) meshes cross each other, beyond one resting on the other."""
    lo, hi = np.maximum(a.bounds[0], b.bounds[0]), np.minimum(a.bounds[1], b.bounds[1])
    if np.any(hi - lo <= OVERLAP_VOXEL_M):
        return False
    box = np.array([lo - OVERLAP_VOXEL_M, hi + OVERLAP_VOXEL_M])
    shared = _surface_voxels(a, box) & _surface_voxels(b, box)
    upper_bottom = max(a.bounds[0, 2], b.bounds[0, 2])
    crossing = [v for v in shared if (v[2] + 1) * OVERLAP_VOXEL_M > upper_bottom + RESTING_BAND_M]
    return len(crossing) > MAX_SHARED_VOXELS


def load_manifest_scene(path: str | Path) -> Scene:
    """Build a Scene from a manifest; raise ManifestError naming the file and field on bad input."""
    path = Path(path)
    data = _read_manifest(path)
    room = data.get("room")
    if not isinstance(room, dict) or "size_m" not in room:
        raise ManifestError(f"{path}: 'room' with 'size_m': [x, y, z] is required")
    size = _vector(room["size_m"], (3,), f"{path}: room.size_m")
    if np.any(size <= 0.5):
        raise ManifestError(f"{path}: room.size_m must be larger than 0.5 m on every axis, got {size.tolist()}")
    up = up_axis_rotation(_text(data, "up_axis", str(path), "z"))
    objects = data.get("objects")
    if not isinstance(objects, list) or not objects:
        raise ManifestError(f"{path}: 'objects' must be a non-empty list")
    rng = np.random.default_rng(0)
    instances = build_structure(size, rng)
    n_structure = len(instances)
    for k, obj in enumerate(objects):
        where = f"{path}: objects[{k}]"
        if not isinstance(obj, dict):
            raise ManifestError(f"{where}: expected a mapping")
        for key in ("mesh", "category", "position_m"):
            if key not in obj:
                raise ManifestError(f"{where}: missing '{key}'")
        category = _text(obj, "category", where)
        caption = _text(obj, "caption", where, f"a {category}")
        material = obj.get("material", "")
        if not isinstance(material, str):
            raise ManifestError(f"{where}.material: expected a string, got {material!r}")
        mesh = _load_mesh((path.parent / _text(obj, "mesh", where)).resolve(), where)
        mesh.apply_transform(up)
        mesh.apply_translation(-mesh.bounds.mean(axis=0) * [1, 1, 0] - [0, 0, mesh.bounds[0, 2]])
        height = float(mesh.extents[2])
        if "height_m" in obj:
            target = _number(obj, "height_m", where, positive=True)
            if height <= 1e-9:
                raise ManifestError(f"{where}: mesh {obj['mesh']} is flat along up_axis; cannot scale it to height_m")
            mesh.apply_scale(target / height)
        elif mesh.extents.max() > max(size) * 2:
            raise ManifestError(
                f"{where}: mesh {obj['mesh']} is {mesh.extents.max():.1f} units across, larger than the room: "
                "give height_m (the mesh's units are probably not metres) or check up_axis"
            )
        yaw = _number(obj, "yaw_deg", where, 0.0)
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.radians(yaw), [0, 0, 1]))
        pos = _vector(obj["position_m"], (2, 3), f"{where}.position_m")
        z = pos[2] if len(pos) == 3 else 0.0
        mesh.apply_translation([pos[0] - mesh.bounds.mean(axis=0)[0], pos[1] - mesh.bounds.mean(axis=0)[1],
                                z - mesh.bounds[0, 2]])
        if np.any(mesh.bounds[0] < -ROOM_TOLERANCE_M) or np.any(mesh.bounds[1] > size + ROOM_TOLERANCE_M):
            raise ManifestError(
                f"{where}: {obj['category']} at {pos.tolist()} reaches outside the room "
                f"(bounds {np.round(mesh.bounds, 3).tolist()}, room {size.tolist()})"
            )
        color = _vector(obj["color"], (3,), f"{where}.color") if "color" in obj else None
        if color is not None and (np.any(color < 0) or np.any(color > 1)):
            raise ManifestError(f"{where}.color: expected three numbers in [0, 1] (RGB), got {obj['color']!r}")
        rgb = _face_colors(mesh, color)
        inst = Instance(len(instances) + 1, category, caption, rgb, "", material, mesh, [mesh])
        for other in instances[n_structure:]:
            if surfaces_overlap(inst.mesh, other.mesh):
                raise ManifestError(
                    f"{where}: {category} ({obj['mesh']}) overlaps {other.category} (instance {other.instance_id}); "
                    "move one of them"
                )
        instances.append(inst)
    return Scene(_text(data, "name", str(path), path.stem), tuple(float(s) for s in size), instances, None)
