"""The env's recorded episodes (``env.episode="recorded"``): which recording an episode replays, where recordings
are cached, and making one with the real mapper on first use.

A world has ``env.recordings`` recordings; ``reset(seed)``'s episode seed picks one (its index is the seed modulo
their number) and still drives the channel's draws. A recording is a real ``never`` episode
(``mapping.team.recording``) made by the env's own team on the recording's episode seed, cached as
``<world cache>/recordings/<scene>-w<world seed>-e<episode seed>-<setting digest>.npz`` (cleared with the world
cache) and refused, with the differing settings named, when it was made by another version of the code, with
other settings or for another world; a refused or truncated file is made again.
"""

from __future__ import annotations

import gc
import hashlib
import json
import re
import time
import warnings
import zlib
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np

from mapping.team.recorded import RecordedTeam
from mapping.team.recording import EpisodeRecorder, Recording, RecordingError
from openmulti_env.environment.observation import DEPTH_STRIDE, TeamObserver
from openmulti_env.environment.rewards import code_digest
from openmulti_env.world.cache import RECORDINGS_FOLDER, package_version, world_cache_dir


class RecordingWarning(UserWarning):
    """A cached recording could not be used (named why) and is made again."""


def recording_seed(world_seed: int, index: int) -> int:
    """The episode seed of a world's ``index``-th recording."""
    return zlib.crc32(f"recording-{int(world_seed)}-{int(index)}".encode())


def recording_meta(tree, world_seed: int, episode_seed: int) -> dict:
    """What a recording depends on: the world, both seeds, perception, the team's learning settings, the probes,
    the map's grid, the learner and device, the package version and the code (the channel, the env's rewards and
    actions do not enter: a recording is one ``never`` episode)."""
    return {"scene": tree.scene, "world_seed": int(world_seed), "episode_seed": int(episode_seed),
            "agents": tree.num_agents, "world": asdict(tree.world), "perception": asdict(tree.perception),
            "team": asdict(tree.team), "probe_points": tree.env.probe_points, "map_size": tree.env.map_size,
            "learner": tree.run.learner, "device": str(tree.run.device), "version": package_version(),
            "code": recording_code()}


def recording_code() -> str:
    """A digest of the code a recording depends on: what plays an episode (``rewards.code_digest``), and what turns
    frames into the observation's cells and the recorded captures (``observation.py``, this module)."""
    digest = hashlib.sha256(code_digest().encode())
    for path in (Path(__file__).with_name("observation.py"), Path(__file__)):
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def recording_path(tree, meta: dict) -> Path:
    """Where the recording of ``meta`` is cached (the digest leaves out version and code: a file of another
    version is found, refused by name and made again, not left behind)."""
    setting = {k: v for k, v in meta.items() if k not in ("version", "code")}
    digest = hashlib.sha256(json.dumps(setting, sort_keys=True, default=str).encode()).hexdigest()[:12]
    scene = re.sub(r"[^A-Za-z0-9_.-]", "_", Path(str(tree.scene)).stem)[:40]
    return world_cache_dir(tree.env.cache_dir) / RECORDINGS_FOLDER / \
        f"{scene}-w{meta['world_seed']}-e{meta['episode_seed']}-{digest}.npz"


class RecordedEpisodes:
    """A world's recordings for one env: ``team(episode_seed)`` is a ``RecordedTeam`` on the recording that
    seed picks, read from memory, the cache, or made with ``real_team(seed)`` (the env's real team)."""

    def __init__(self, tree, world_seed: int, real_team: Callable[[int], object], points: np.ndarray,
                 normals: np.ndarray, observer: TeamObserver):
        self.tree, self.world_seed, self.real_team = tree, int(world_seed), real_team
        self.points, self.normals, self.observer = points, normals, observer
        self.memory: dict[int, Recording] = {}
        self.made = 0
        """Recordings this object made (not found in the cache)."""
        self.record_s = 0.0

    def team(self, episode_seed: int) -> RecordedTeam:
        index = int(episode_seed) % self.tree.env.recordings
        return RecordedTeam(self.recording(index), self.tree.team, self.tree.channel, seed=episode_seed)

    @property
    def complete(self) -> bool:
        """Every recording of the world is in memory: the real team (renderer, encoders) is not needed again."""
        return len(self.memory) == self.tree.env.recordings

    def release(self, world, frames) -> None:
        """Once every recording is in memory: drop what only making one needs (the rendered frames, the GL context,
        the culled surface the probes were sampled from: 40-130 MB a world at ``rl_lite``), so that a training worker
        keeps many recorded worlds."""
        frames.clear()
        world.close()
        world.surface = None
        gc.collect()  # the surface's meshes hold reference cycles: freed now, once a world, not at some later sweep

    def recording(self, index: int) -> Recording:
        if index in self.memory:
            return self.memory[index]
        meta = recording_meta(self.tree, self.world_seed, recording_seed(self.world_seed, index))
        path = recording_path(self.tree, meta)
        found = None
        if path.exists():
            try:
                found = Recording.load(path, expected=meta)
            except RecordingError as exc:  # every unreadable or foreign file is one (Recording.load)
                warnings.warn(f"{exc}; recording it again", RecordingWarning, stacklevel=3)
        if found is None:
            found = self.make(meta)
            found.save(path)
        self.memory[index] = found
        return found

    def make(self, meta: dict) -> Recording:
        """One real ``never`` episode on the recording's seed, captured round by round."""
        from tqdm import tqdm  # noqa: PLC0415

        start = time.perf_counter()
        print(f"[openmulti] recording an episode of {meta['scene']!r} (world seed {meta['world_seed']}, episode seed "
              f"{meta['episode_seed']}) with the real mapper, once; it is cached in {recording_path(self.tree, meta).parent}")
        team = self.real_team(meta["episode_seed"])
        try:
            recorder = EpisodeRecorder(team, self.points, self.normals, self.observer.column_grid,
                                       self.cell_centres, DEPTH_STRIDE)
            with tqdm(total=team.rounds_total(), desc="recording", unit="round", leave=False) as bar:
                recording = recorder.record(meta, progress=lambda _: bar.update())
        finally:
            team.release()
        self.made += 1
        self.record_s += time.perf_counter() - start
        return recording

    def cell_centres(self, points: np.ndarray) -> np.ndarray:
        """(U, 3) the centres (z = 0) of the map cells ``points`` fall on, once each."""
        grid = self.observer.grid
        cells = np.unique(grid.flat(np.asarray(points, float).reshape(-1, 3)))
        rows, cols = np.divmod(cells, grid.size)
        xy = grid.origin_xy + (np.stack([cols, rows], axis=1) + 0.5) * grid.cell_m
        return np.concatenate([xy, np.zeros((len(xy), 1))], axis=1)


__all__ = ["RecordedEpisodes", "RecordingWarning", "recording_meta", "recording_path", "recording_seed"]
