"""The fixed-rate front as the reward's price of bytes (``env.reward_baseline="front"``).

The schedules of the front (``never``, ``every:K``, ``rate:Q``, ``always``) are played once on the same episode
(world and episode seed) and cached; their (team MB, team completion) points make a front F: the upper
envelope, straight lines between kept points, flat past the last (``front``; ``studies.learned_vs_fixed``
judges policies on the same function). A step pays

    (gain - never's gain at that step - (F(MB sent so far) - F(MB sent before this step))) / (always's final - never's final)

so the return of an episode is (final completion - F(MB the team sent)) / span: the margin over the fixed-rate
front at the policy's bytes, the figure a learned schedule is judged by, in units of what talking adds in that
world. Every schedule on the front returns 0 (less ``budget_penalty`` for messages refused over a budget); a byte
costs what it buys on the front at the bytes already sent (the first megabytes cost most: the front is steepest
there).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from functools import cached_property
from typing import Callable, Sequence

import numpy as np

from mapping.team import RoundPlan

FRONT_SCHEDULES = ("every:2", "every:3", "every:4", "every:6", "every:8", "rate:0.1", "rate:0.25", "rate:0.5")
"""Played beside ``never`` and ``always`` (the benchmark's fixed-rate front; down to 10-17 % of ``always``'s
bytes, so that cheap sending is priced by a schedule of about its bytes)."""
FRONT_FORMAT = 1


def front_points(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """The Pareto front of (MB, completion) points: each kept point completes more than every cheaper one."""
    keep: list[tuple[float, float]] = []
    for mb, c in sorted(points, key=lambda p: (p[0], -p[1])):  # under a cheaper (or equally cheap) one: dominated
        if keep and (c <= keep[-1][1] or mb == keep[-1][0]):
            continue
        keep.append((float(mb), float(c)))
    return keep


def front(points: Sequence[tuple[float, float]]) -> Callable[[float], float]:
    """``front_points`` as a function of MB: straight lines between kept points, flat past the last (not their
    concave hull: a schedule that mixed two others round by round is not on it)."""
    keep = front_points(points)
    if not keep:
        raise ValueError("a front needs at least one (MB, completion) point")
    xs, ys = np.array([p[0] for p in keep]), np.array([p[1] for p in keep])
    return lambda mb: float(np.interp(mb, xs, ys))


def schedule_plan(schedule: str, num_agents: int, round_index: int, rng: np.random.Generator) -> RoundPlan:
    """Round ``round_index``'s (0-based) plan of a fixed schedule: ``never``, ``always``, ``every:K`` (everything
    on rounds 0, K, 2K, ...) or ``rate:Q`` (each entry, parameters and rays per peer, 1 with probability Q)."""
    head, _, arg = schedule.partition(":")
    if head in ("never", "always") and not arg:
        return RoundPlan.always(num_agents) if head == "always" else RoundPlan.never(num_agents)
    if head == "every" and arg.isdigit() and int(arg) >= 1:
        return RoundPlan.always(num_agents) if round_index % int(arg) == 0 else RoundPlan.never(num_agents)
    if head == "rate":
        try:
            q = float(arg)
        except ValueError:
            q = -1.0
        if 0.0 <= q <= 1.0:
            off = ~np.eye(num_agents, dtype=bool)
            draws = rng.random((2, num_agents, num_agents)) < q
            return RoundPlan(draws[0] & off, draws[1] & off)
    raise ValueError(f"unknown fixed schedule {schedule!r}: never, always, every:K (K >= 1) or rate:Q (0 <= Q <= 1)")


def schedule_rng(schedule: str, episode_seed: int) -> np.random.Generator:
    """The draws of a ``rate:Q`` schedule on one episode: fixed by the episode seed and the schedule's name."""
    name = int(hashlib.sha256(schedule.encode()).hexdigest()[:8], 16)
    return np.random.default_rng([int(episode_seed), name])


@dataclass(frozen=True)
class FrontPoints:
    """One episode's fixed schedules: each one's team MB and final team completion (fraction)."""

    schedules: tuple[str, ...]
    mb: np.ndarray
    """(K,) megabytes the team sent."""
    completion: np.ndarray
    """(K,) the team's mean completion ratio at the end."""

    @cached_property
    def curve(self) -> Callable[[float], float]:
        """``front`` of these points, built once (every step of an episode reads it)."""
        return front(list(zip(self.mb.tolist(), self.completion.tolist())))

    def as_record(self) -> dict:
        return {"format": FRONT_FORMAT, "schedules": list(self.schedules), "mb": self.mb.tolist(),
                "completion": self.completion.tolist()}

    @staticmethod
    def from_record(record: dict) -> "FrontPoints":
        if record.get("format") != FRONT_FORMAT:
            raise ValueError(f"front record of format {record.get('format')!r}, expected {FRONT_FORMAT}")
        points = FrontPoints(tuple(record["schedules"]), np.asarray(record["mb"], float),
                             np.asarray(record["completion"], float))
        if not len(points.schedules) == len(points.mb) == len(points.completion):
            raise ValueError("a front record's schedules, MB and completions differ in length")
        return points


def front_price(points: FrontPoints, mb_before: float, mb_after: float) -> float:
    """What the front completes more at the team's MB after this step than before it (a fraction)."""
    return points.curve(mb_after) - points.curve(mb_before)


def front_key(baseline_key: str, schedules: Sequence[str]) -> str:
    """A cache key of the front's episodes: the never/always key (world, seeds, settings, code) and the schedules."""
    parts = {"baseline": baseline_key, "schedules": list(schedules), "format": FRONT_FORMAT}
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:32]
