"""The env's rewards, and the per-world baseline that gives them signal.

Raw (``env.reward_baseline="none"``): a step pays the gain of the completion ratio (the team's mean, or the
agent's own) minus ``comm_cost_per_mb`` x the megabytes sent: a room that maps easily pays more whatever the
team sends, and a room of big networks costs more (docs/learning.md measures how much that spread weighs).

Normalised (``"never_always"``): the same episode (world and episode seed) is played twice more, once with
``never`` and once with ``always``, and a step pays

    (gain - never's gain at that step) / (always's final - never's final)  -  comm_cost_of_always x MB / always's MB

so an episode's return is the share of what talking can add in *this* world that the team got, minus the
price of the share of ``always``'s bytes it spent: 0 for ``never``, 1 - comm_cost_of_always for ``always``,
in every world where ``always`` adds at least ``GAIN_FLOOR`` (and less ``budget_penalty`` for refused messages). Subtracting never's gain step by step also takes out each agent's own mapping progress,
which no communication decision moves. The two episodes are cached on disk per (world, episode seed and
everything that shapes the maps), so a training run that revisits its worlds' episodes pays them once.

Front (``"front"``): the same, with the price of bytes read off the episode's fixed-rate front instead of a
constant (``openmulti_env.environment.reward_front``).
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable, TypeVar

import numpy as np

from mapping.perception.model_cache import cache_root
from mapping.safe_parse import load_json
from openmulti_env.environment.reward_front import (FRONT_SCHEDULES, FrontPoints, front_key, front_price,
                                                    schedule_plan, schedule_rng)

T = TypeVar("T")
GAIN_FLOOR = 0.02
"""Smallest ``always - never`` final completion (a fraction) the normalised reward divides by: a world where
talking adds under two points would otherwise pay noise x 50."""
BASELINE_FORMAT = 1


@dataclass(frozen=True)
class BaselineEpisodes:
    """``never`` and ``always`` on one episode: completion (fraction) of each agent after each step, with the
    start (all zero) as row 0, and the MB each agent sent in ``always``."""

    never: np.ndarray
    """(T + 1, N) completion ratios."""
    always: np.ndarray
    """(T + 1, N)."""
    always_mb: np.ndarray
    """(N,) megabytes each agent sent over the episode."""

    def as_record(self) -> dict:
        return {"format": BASELINE_FORMAT, "never": self.never.tolist(), "always": self.always.tolist(),
                "always_mb": self.always_mb.tolist()}

    @staticmethod
    def from_record(record: dict) -> "BaselineEpisodes":
        if record.get("format") != BASELINE_FORMAT:
            raise ValueError(f"baseline record of format {record.get('format')!r}, expected {BASELINE_FORMAT}")
        return BaselineEpisodes(np.asarray(record["never"], float), np.asarray(record["always"], float),
                                np.asarray(record["always_mb"], float))

    def gain_share(self, step: int, team: bool) -> tuple[np.ndarray, np.ndarray]:
        """(never's gain at ``step`` (1-based; 0 past the end of the stored episode), the denominator ``always -
        never`` at the end), per agent or, with ``team``, the team's mean broadcast to every agent."""
        if step < len(self.never):
            never_gain = self.never[step] - self.never[step - 1]
        else:
            never_gain = np.zeros_like(self.never[-1])
        span = self.always[-1] - self.never[-1]
        if team:
            never_gain = np.full_like(never_gain, never_gain.mean())
            span = np.full_like(span, span.mean())
        return never_gain, np.maximum(span, GAIN_FLOOR)


@lru_cache(maxsize=1)
def code_digest() -> str:
    """A digest of the code that plays an episode (the learner, the world and its frames, the env's rounds and
    rewards): cached baselines are played again after any change to it, not read stale."""
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    for folder in (root / "mapping", root / "openmulti_env" / "world"):
        for path in sorted(folder.rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode() + path.read_bytes())
    for path in (Path(__file__), Path(__file__).with_name("parallel_env.py"), Path(__file__).with_name("reward_front.py")):
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def baseline_key(tree, world_seed: int, episode_seed: int) -> str:
    """A digest of what decides the two episodes: the scene, both seeds, the world, perception, team and channel
    settings, the horizon, the probes, the learner and device, the code, and for a recorded env its recordings (the
    env's reward and observation settings do not enter)."""
    parts = {"scene": tree.scene, "world_seed": int(world_seed), "episode_seed": int(episode_seed),
             "world": asdict(tree.world), "perception": asdict(tree.perception), "team": asdict(tree.team),
             "channel": asdict(tree.channel), "probe_points": tree.env.probe_points, "horizon": tree.env.horizon,
             "learner": tree.run.learner, "device": str(tree.run.device), "format": BASELINE_FORMAT,
             "code": code_digest()}
    if tree.env.episode != "real":  # a recorded env's baselines are its model's episodes, never the real ones
        parts.update(episode=tree.env.episode, recordings=tree.env.recordings)
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:32]


def write_record(path: Path, record: dict) -> None:
    """A cache entry written whole (a temporary file, then renamed): readers never see half of one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.{threading.get_ident()}.tmp")
    tmp.write_text(json.dumps(record))
    os.replace(tmp, path)


def read_record(path: Path, parse: Callable[[dict], T]) -> T | None:
    """A cache entry, or None if it is missing, torn or of an old format (then it is played again)."""
    if not path.exists():
        return None
    try:
        return parse(load_json(path))
    except (ValueError, KeyError, TypeError, AttributeError, OSError):  # JSONDecodeError is a ValueError
        return None


class RewardBaselines:
    """Per-episode ``BaselineEpisodes`` (and, for the front reward, ``FrontPoints``), from memory, the disk cache,
    or ``play(episode_seed, schedule)`` (the env's way to play a fixed schedule, ``reward_front.schedule_plan``'s
    names: it returns the (T + 1, N) completions and the (N,) MB sent)."""

    def __init__(self, tree, world_seed: int, play: Callable[[int, str], tuple[np.ndarray, np.ndarray]],
                 schedules: tuple[str, ...] = FRONT_SCHEDULES):
        self.tree, self.world_seed, self.play, self.schedules = tree, int(world_seed), play, tuple(schedules)
        folder = tree.env.cache_dir
        self.folder = (Path(folder).expanduser() if folder is not None else cache_root()) / "reward_baselines"
        self.memory: dict[int, BaselineEpisodes] = {}
        self.fronts: dict[int, FrontPoints] = {}
        self.played = 0
        """Episodes played (not found in a cache) by this object: two per new episode seed (and one per front
        schedule for the front reward)."""

    def episode(self, episode_seed: int) -> BaselineEpisodes:
        if episode_seed in self.memory:
            return self.memory[episode_seed]
        path = self.folder / f"{baseline_key(self.tree, self.world_seed, episode_seed)}.json"
        found = read_record(path, BaselineEpisodes.from_record)
        if found is None:
            never, _ = self.play(episode_seed, "never")
            always, always_mb = self.play(episode_seed, "always")
            self.played += 2
            found = BaselineEpisodes(np.asarray(never, float), np.asarray(always, float), np.asarray(always_mb, float))
            write_record(path, found.as_record())
        self.memory[episode_seed] = found
        return found

    def front(self, episode_seed: int) -> FrontPoints:
        """The episode's fixed-rate front: ``never`` and ``always`` (``episode``) and each of ``schedules``."""
        if episode_seed in self.fronts:
            return self.fronts[episode_seed]
        base = self.episode(episode_seed)
        path = self.folder / f"front-{front_key(baseline_key(self.tree, self.world_seed, episode_seed), self.schedules)}.json"
        played = read_record(path, FrontPoints.from_record)
        if played is None:  # the key holds the schedules: a record found is of these
            mb, completion = [], []
            for schedule in self.schedules:
                completions, sent = self.play(episode_seed, schedule)
                self.played += 1
                mb.append(float(np.sum(sent)))
                completion.append(float(np.mean(completions[-1])))
            played = FrontPoints(self.schedules, np.array(mb), np.array(completion))
            write_record(path, played.as_record())
        sent = played.mb > 0  # a draw that sent nothing is never again: never's own episode anchors F(0)
        found = FrontPoints(("never",) + tuple(np.array(self.schedules)[sent]) + ("always",),
                            np.concatenate([[0.0], played.mb[sent], [float(base.always_mb.sum())]]),
                            np.concatenate([[float(base.never[-1].mean())], played.completion[sent],
                                            [float(base.always[-1].mean())]]))
        self.fronts[episode_seed] = found
        return found


def play_fixed(new_team: Callable[[], object], num_agents: int, horizon: int | None, points: np.ndarray,
               normals: np.ndarray, schedule: str, episode_seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A fixed schedule (``reward_front.schedule_plan``: ``never``, ``always``, ``every:K``, ``rate:Q``) on a fresh
    team from ``new_team()``: (T + 1, N) completions (the share of the probe ``points`` each agent's map
    reproduces after each round, 0 at the start) and (N,) MB sent."""
    team = new_team()
    rng = schedule_rng(schedule, episode_seed)
    completions = [np.zeros(num_agents)]
    try:
        while not team.done and (horizon is None or len(completions) <= horizon):
            team.round(schedule_plan(schedule, num_agents, len(completions) - 1, rng))
            covered = team.surface_coverage(points, normals)
            completions.append(np.array([float(np.mean(c)) for c in covered]))
        mb = np.array([s.bytes_sent_total for s in team.snapshots()], float) / 1e6
    finally:
        team.release()
    return np.stack(completions), mb


def step_rewards(env_settings, gains: np.ndarray, mb: np.ndarray, refused: np.ndarray, step: int,
                 baseline: BaselineEpisodes | None, front: FrontPoints | None = None,
                 mb_before: float = 0.0) -> np.ndarray:
    """(N,) rewards of one step (``step`` 1-based) from each agent's completion gain (fraction), MB sent and
    messages refused; ``baseline`` is required with ``reward_baseline="never_always"`` (module docstring), and
    ``front`` with ``"front"``, where ``mb_before`` is what the team sent before this step."""
    n = len(gains)
    team = env_settings.reward != "individual"
    penalty = env_settings.budget_penalty * refused
    if env_settings.reward_baseline == "none":
        own = gains - env_settings.comm_cost_per_mb * mb - penalty
        if not team:
            return own
        return np.full(n, gains.mean() - (env_settings.comm_cost_per_mb * mb.sum() + penalty.sum()) / n)
    if baseline is None:
        raise RuntimeError("the normalised reward needs the episode's never/always baseline")
    never_gain, span = baseline.gain_share(step, team)
    if env_settings.reward_baseline == "front":
        if front is None or not team:
            raise RuntimeError("the front reward needs the episode's fixed-rate front and the team reward")
        price = front_price(front, mb_before, mb_before + float(mb.sum()))
        return np.full(n, (gains.mean() - never_gain[0] - price) / span[0] - penalty.sum() / n)
    mb_always = np.maximum(baseline.always_mb, 1e-9)
    if team:
        gain = (gains.mean() - never_gain[0]) / span[0]
        cost = env_settings.comm_cost_of_always * mb.sum() / mb_always.sum()
        return np.full(n, gain - cost - penalty.sum() / n)
    return (gains - never_gain) / span - env_settings.comm_cost_of_always * mb / mb_always - penalty


class EpisodeRewards:
    """The env's rewards one episode at a time: the episode's baselines (none, never/always, or with its front)
    and the MB the team sent so far (the front prices a step's bytes at what was sent before it)."""

    def __init__(self, env_settings, baselines: RewardBaselines | None) -> None:
        if env_settings.reward_baseline != "none" and baselines is None:
            raise ValueError(f"reward_baseline={env_settings.reward_baseline!r} needs the episodes' baselines")
        self.settings, self.baselines = env_settings, baselines
        self.baseline: BaselineEpisodes | None = None
        self.front: FrontPoints | None = None
        self.sent_mb = 0.0

    def start(self, episode_seed: int) -> None:
        """A new episode: its baselines (played or read from the cache) and nothing sent yet."""
        if self.baselines is not None:
            self.baseline = self.baselines.episode(episode_seed)
            self.front = self.baselines.front(episode_seed) if self.settings.reward_baseline == "front" else None
        self.sent_mb = 0.0

    def step(self, gains: np.ndarray, mb: np.ndarray, refused: np.ndarray, step: int) -> np.ndarray:
        """(N,) rewards of step ``step`` (1-based): ``step_rewards`` on this episode's baselines."""
        values = step_rewards(self.settings, gains, mb, refused, step, self.baseline, self.front, self.sent_mb)
        self.sent_mb += float(np.sum(mb))
        return values
