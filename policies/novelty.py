"""``novelty``: a scripted schedule that reads the observation's per-peer link state.

Send parameters to a peer when it lacks instances of mine or my map moved materially since the copy it
holds; share rays with a peer that holds my parameters (eq. 13 renders my views through the copy of my
instances it holds, so rays are worth little before it has them); and with a byte budget, do not spend
ahead of the path: when the share of the budget spent runs ahead of the share of the path walked by more
than ``slack``, stay silent. Settings: ``novelty:change=0.1,gap=1,rays=held,slack=0.1``.
"""

from __future__ import annotations

import math

from dataclasses import dataclass, fields
from typing import Mapping

import numpy as np

from openmulti_env.environment.layout import AGE_SCALE, agent_feature, link_feature

RAY_RULES = ("held", "always", "never", "with_params")


@dataclass(frozen=True)
class NoveltySettings:
    """The heuristic's settings (``novelty:name=value,...``)."""

    change: float = 0.1
    """Send parameters when the mean relative change of my instances since the peer's copy reaches this."""
    gap: int = 1
    """At least this many rounds between two parameter messages to the same peer."""
    rays: str = "held"
    """Share rays with: ``held`` (peers holding my parameters), ``with_params`` (peers I send parameters to
    this round), ``always`` or ``never``."""
    slack: float = 0.1
    """With a budget: stay silent while the share of budget spent exceeds the share of path walked by this."""

    @staticmethod
    def parse(text: str) -> "NoveltySettings":
        """``""`` or ``"change=0.2,gap=2"``; ValueError naming a bad or unknown setting."""
        if not text:
            return NoveltySettings()
        known = {f.name: f.type for f in fields(NoveltySettings)}
        values = {}
        for item in text.split(","):
            key, eq, value = item.partition("=")
            if not eq or key not in known:
                raise ValueError(f"novelty settings are name=value pairs of {sorted(known)}, got {item!r}")
            values[key] = value if key == "rays" else (int(value) if key == "gap" else float(value))
        settings = NoveltySettings(**values)
        if settings.rays not in RAY_RULES:
            raise ValueError(f"rays must be one of {RAY_RULES}, got {settings.rays!r}")
        if settings.gap < 1 or not (math.isfinite(settings.change) and settings.change >= 0) \
                or not (math.isfinite(settings.slack) and settings.slack >= 0):
            raise ValueError(f"gap must be >= 1, change and slack finite and >= 0; got {settings}")
        return settings

    def __str__(self) -> str:
        return ",".join(f"{f.name}={getattr(self, f.name)}" for f in fields(self))


class NoveltyPolicy:
    """The heuristic for every agent of a team (see the module docstring)."""

    reads_observations = True

    def __init__(self, settings: NoveltySettings | None = None):
        self.settings = settings or NoveltySettings()

    def act(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        """One agent's (2 * (N - 1),) int8 action from its observation."""
        s = self.settings
        holds, change = link_feature(observation, "holds"), link_feature(observation, "change")
        since = link_feature(observation, "since_params") * AGE_SCALE
        params = ((holds < 1.0) | (change >= s.change)) & (np.round(since) + 1 >= s.gap)  # since: 0 = last round
        if s.rays == "held":
            rays = holds > 0
        elif s.rays == "with_params":
            rays = params.copy()
        else:
            rays = np.full(holds.shape, s.rays == "always")
        spent = 1.0 - float(agent_feature(observation, "budget_left"))
        if spent > float(agent_feature(observation, "progress")) + s.slack:
            params[:], rays[:] = False, False
        return np.concatenate([params, rays]).astype(np.int8)

    def __call__(self, observations: Mapping[str, Mapping[str, np.ndarray]], infos=None,
                 step: int = 0) -> dict[str, np.ndarray]:
        """Actions of every agent that has an observation."""
        if observations is None:
            raise ValueError("novelty reads observations: call it with the env's observations")
        return {agent: self.act(obs) for agent, obs in observations.items()}
