"""A disk cache of the world's geometry: the culled observable surface and the planned paths.

Culling and path planning take 0.4 s (``tiny``) to 10 s (``fast``, 600k faces) per world, and an env
resets many times and runs in many processes. An entry is keyed by everything that shapes the world
(scene name, or a manifest's bytes and its meshes', seed, ``WorldConfig``, package version and this
file's format), written atomically (a temporary file renamed into place), and read back with
``allow_pickle=False``. The scene itself is rebuilt from its recipe (0.1 s). A world built cold is read
back from the entry it wrote, so a cold and a warm reset give the same episode bit for bit.

The folder is ``$OPENMULTI_CACHE/worlds`` (default ``~/.cache/openmulti/worlds``) or the one given;
``clear_world_cache`` empties it (``openmulti cache --clear``); the least recently used entries go
when the folder outgrows its cap; a corrupt entry is rebuilt with a warning.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import warnings
import zipfile
from dataclasses import asdict
from importlib import metadata
from pathlib import Path

import numpy as np
import trimesh

from mapping.perception.model_cache import cache_root
from mapping.safe_parse import load_data
from openmulti_env.world.presets import make_scene
from openmulti_env.world.visibility import ObservableSurface
from openmulti_env.world.world import World, WorldConfig

CACHE_FORMAT = 1
RECORDINGS_FOLDER = "recordings"
"""The sub-folder of recorded episodes (``openmulti_env.environment.recorded_episode``), cleared with the worlds."""
ENTRY_NAME = re.compile(r"[0-9a-f]{32}\.npz")
"""What an entry's file is called (``world_cache_key``): the only files clearing and trimming touch."""
_KEYS = ("vertices", "faces", "face_colors", "face_instance_ids", "visible", "viewpoints", "path_lengths", "poses")


class WorldCacheWarning(UserWarning):
    """A cache entry could not be used (corrupt or unreadable) and the world was rebuilt."""


def world_cache_dir(cache_dir: str | Path | None = None) -> Path:
    """The folder of world entries (``cache_dir`` as given, else ``<cache root>/worlds``)."""
    return Path(cache_dir).expanduser() if cache_dir is not None else cache_root() / "worlds"


def world_cache_key(scene: str, seed: int, config: WorldConfig) -> str:
    """A hex digest of everything that shapes the world's geometry."""
    parts = {"scene": scene, "seed": int(seed), "config": asdict(config), "format": CACHE_FORMAT,
             "version": package_version()}
    path = Path(scene)
    if path.suffix.lower() in (".json", ".yaml", ".yml") and path.is_file():
        parts["manifest"] = _manifest_digest(path)
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:32]


def cached_world(scene: str, seed: int, config: WorldConfig, cache_dir: str | Path | None = None,
                 max_mb: float = 2048.0, say=print) -> tuple[World, bool]:
    """The world, from the cache when it holds it; returns ``(world, hit)``.

    A miss builds the world (``say`` tells what it is building), writes the entry, trims the folder to
    ``max_mb`` and returns the world as read back from the entry.
    """
    folder = world_cache_dir(cache_dir)
    entry = folder / f"{world_cache_key(scene, seed, config)}.npz"
    if entry.is_file():
        try:
            world = _read(entry, scene, seed, config)
            os.utime(entry)  # least recently used goes first
            return world, True
        except (OSError, ValueError, KeyError, EOFError, IndexError, zipfile.BadZipFile) as exc:
            warnings.warn(f"world cache entry {entry} is unreadable ({exc}); rebuilding it", WorldCacheWarning,
                          stacklevel=2)
    say(f"[openmulti] building the world of {scene!r} (seed {seed}, {config.num_agents} agents): culling the "
        f"observable surface and planning paths; it is cached in {folder}")
    built = World.build(scene, seed=seed, config=config)
    try:
        _write(entry, built)
        world = _read(entry, scene, seed, config, scene_object=built.scene)
        trim_world_cache(folder, max_mb, keep=entry)
        return world, False
    except OSError as exc:  # a read-only cache is only a slower reset
        warnings.warn(f"could not write the world cache entry {entry} ({exc}); using the world uncached",
                      WorldCacheWarning, stacklevel=2)
        return built, False


def clear_world_cache(cache_dir: str | Path | None = None) -> int:
    """Delete every entry (files named as ``world_cache_key`` names them) and every recorded episode (the
    ``recordings`` sub-folder); nothing else in the folder. Returns the bytes freed."""
    folder = world_cache_dir(cache_dir)
    freed = 0
    for path in cache_entries(folder) + sorted((folder / RECORDINGS_FOLDER).glob("*.npz")):
        freed += path.stat().st_size
        path.unlink(missing_ok=True)
    return freed


def trim_world_cache(folder: Path, max_mb: float, keep: Path | None = None) -> None:
    """Remove the least recently used entries until the folder holds at most ``max_mb``."""
    entries = sorted(cache_entries(folder), key=lambda p: p.stat().st_mtime)
    total = sum(p.stat().st_size for p in entries)
    for path in entries:
        if total <= max_mb * 1e6:
            break
        if keep is not None and path == keep:
            continue
        total -= path.stat().st_size
        path.unlink(missing_ok=True)


def cache_entries(folder: Path) -> list[Path]:
    """The entries in ``folder``: files named as ``world_cache_key`` names them (a user's own ``.npz``
    files beside them are never touched)."""
    return [p for p in folder.glob("*.npz") if ENTRY_NAME.fullmatch(p.name) and p.is_file()]


def _write(entry: Path, world: World) -> None:
    surface = world.surface
    entry.parent.mkdir(parents=True, exist_ok=True)
    tmp = entry.with_name(f".{entry.stem}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            np.savez(f, vertices=np.asarray(surface.mesh.vertices, np.float64),
                     faces=np.asarray(surface.mesh.faces, np.int64),
                     face_colors=np.asarray(surface.mesh.visual.face_colors, np.uint8),
                     face_instance_ids=np.asarray(surface.face_instance_ids), visible=np.asarray(surface.visible),
                     viewpoints=np.asarray(surface.viewpoints, np.float64),
                     path_lengths=np.array([len(p) for p in world.agent_poses], np.int64),
                     poses=np.concatenate(world.agent_poses).astype(np.float64))
        os.replace(tmp, entry)
    finally:
        tmp.unlink(missing_ok=True)


def _read(entry: Path, scene: str, seed: int, config: WorldConfig, scene_object=None) -> World:
    with np.load(entry, allow_pickle=False) as z:
        missing = [k for k in _KEYS if k not in z.files]
        if missing:
            raise KeyError(f"missing arrays {missing}")
        data = {k: z[k] for k in _KEYS}
    if len(data["path_lengths"]) != config.num_agents:
        raise ValueError(f"{len(data['path_lengths'])} paths for {config.num_agents} agents")
    mesh = trimesh.Trimesh(data["vertices"], data["faces"], face_colors=data["face_colors"], process=False)
    if len(data["face_instance_ids"]) != len(mesh.faces) or len(data["visible"]) != len(mesh.faces):
        raise ValueError("face labels do not match the mesh")
    surface = ObservableSurface(mesh, data["face_instance_ids"], data["visible"].astype(bool), data["viewpoints"])
    cuts = np.cumsum(data["path_lengths"])[:-1]
    poses = [p.copy() for p in np.split(data["poses"], cuts)]
    sc = scene_object if scene_object is not None else make_scene(scene, seed)
    return World(sc, surface, poses, config.sensor.intrinsics(), config, seed)


def _manifest_digest(path: Path) -> str:
    """The manifest's bytes and those of every mesh it names (a changed mesh is a new world)."""
    h = hashlib.sha256(path.read_bytes())
    try:
        spec = load_data(path)
        for obj in (spec or {}).get("objects", []) or []:
            mesh = path.parent / str(obj.get("mesh", ""))
            if mesh.is_file():
                h.update(mesh.read_bytes())
    except (OSError, ValueError, AttributeError, TypeError):  # ParseError is a ValueError
        pass  # a manifest the loader will reject (and name the problem): its bytes are key enough
    return h.hexdigest()


def package_version() -> str:
    try:
        return metadata.version("openmulti")
    except metadata.PackageNotFoundError:
        return "0+unknown"
