"""``instance_novelty``: a scripted what-to-send schedule on the ``instances`` action form.

Per peer, send the instances it lacks, those whose copy there moved by more than ``change`` (relative L2),
and those it maps too once they moved by more than ``shared`` (parameter consistency, eq. 12, needs fresh
copies of exactly these); nothing else. It asks regardless of the link's last state (a link that is down
carries nothing and costs nothing, and one that comes up this round should not go unused). Rays as ``novelty``:
``held`` (to peers that hold any of my instances), ``with_params``, ``always`` or ``never``. With a byte budget,
stay silent while the share of the budget spent runs ahead of the share of the path walked by ``slack``.
Settings in the name: ``instance_novelty:change=0.03,shared=0.02,rays=held,slack=0.1,after=0,start=0,final=0.01``;
``instance_novelty:change=1,after=999,final=0`` sends each network once, at its final state in the path's last
round, and nothing before (the cheapest schedule that ends with every peer holding every final network).

The minimum a mapping team needs is each instance's network at each peer once plus exchange where two
agents map one instance (docs/schedules.md): this rule is that minimum, refreshed when a copy goes stale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Mapping

import numpy as np

from openmulti_env.environment.layout import agent_feature, instance_feature, link_feature, link_state

RAY_RULES = ("held", "always", "never", "with_params")


@dataclass(frozen=True)
class InstanceNoveltySettings:
    """The rule's settings (``instance_novelty:name=value,...``)."""

    change: float = 0.03
    """Send an instance whose copy at the peer moved by more than this (relative L2 change). Chosen at
    ``rl_small`` on room0 (0.1 lost 12 points there: a copy 10 % stale pulls the peer's own network through
    eq. 12 and stays drawn as it was)."""
    shared: float = 0.02
    """Send an instance the peer maps too once its copy there moved by more than this."""
    rays: str = "held"
    """Share rays with: ``held`` (peers holding any of my instances), ``with_params``, ``always`` or ``never``."""
    slack: float = 0.1
    """With a budget: stay silent while the share of budget spent exceeds the share of path walked by this."""
    after: int = 0
    """Send instances the peer does not map only from this round on (0: from the start). Set to an episode's
    last round it is the hindsight rule: each network reaches each peer once, at its final state, and only
    instances two agents map are exchanged before (it knows when the episode ends: a bound, not a schedule)."""

    start: int = 0
    """Send nothing before this round (0: from the start): the rule opened at a fixed round, the timing a learned
    team gate over the rule (``--payload instance_novelty``) has to beat."""
    final: float = 0.01
    """In the path's last round (known from ``progress``: its own path's length) send every instance whose copy
    moved by more than this: each peer then ends with the final state (1: no final push)."""

    @staticmethod
    def parse(text: str) -> "InstanceNoveltySettings":
        """``""`` or ``"change=0.2,shared=0.05"``; ValueError naming a bad or unknown setting."""
        if not text:
            return InstanceNoveltySettings()
        known = [f.name for f in fields(InstanceNoveltySettings)]
        values: dict = {}
        for item in text.split(","):
            key, eq, value = item.partition("=")
            if not eq or key not in known:
                raise ValueError(f"instance_novelty settings are name=value pairs of {known}, got {item!r}")
            try:
                values[key] = value if key == "rays" else (int(value) if key in ("after", "start") else float(value))
            except ValueError:
                raise ValueError(f"instance_novelty setting {key} needs a number, got {value!r}") from None
        for key in ("after", "start"):
            if values.get(key, 0) < 0:
                raise ValueError(f"{key} must be a round >= 0, got {values[key]}")
        settings = InstanceNoveltySettings(**values)
        if settings.rays not in RAY_RULES:
            raise ValueError(f"rays must be one of {RAY_RULES}, got {settings.rays!r}")
        for name in ("change", "shared", "slack", "final"):
            value = getattr(settings, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")
        return settings

    def __str__(self) -> str:
        return ",".join(f"{f.name}={getattr(self, f.name)}" for f in fields(self))


def last_round(observation: Mapping[str, np.ndarray], step: int) -> bool:
    """Whether round ``step`` reads the last frames of the agent's path: after ``step`` rounds it has read the
    share ``progress`` of it, so the path has ``step / progress`` rounds (unknown in round 0)."""
    progress = float(agent_feature(observation, "progress"))
    return step > 0 and progress > 0 and step + 1 >= math.ceil(step / progress - 1e-6)


class InstanceNoveltyPolicy:
    """The rule for every agent of a team (see the module docstring)."""

    reads_observations = True
    action_form = "instances"

    def __init__(self, settings: InstanceNoveltySettings | None = None):
        self.settings = settings or InstanceNoveltySettings()

    def act(self, observation: Mapping[str, np.ndarray], step: int = 0) -> np.ndarray:
        """One agent's ((N - 1)(M + 2),) int8 action from its observation in round ``step``."""
        s = self.settings
        present = instance_feature(observation, "present") > 0
        lacks = instance_feature(observation, "lacks") > 0
        change = instance_feature(observation, "change")
        shared = instance_feature(observation, "shared") > 0
        peers = link_state(observation, "up").shape  # (N-1,): whether a link is up is decided in the round itself
        novel = (lacks | (change > s.change)) & (step >= s.after)
        final = last_round(observation, step)
        if final:
            novel |= change > s.final
        send = present & (novel | (shared & (change > s.shared)))  # (N-1, M)
        new = np.full(peers, step >= s.after or final)  # what appears this round: the peer lacks it by definition
        if s.rays == "held":
            rays = link_feature(observation, "holds") > 0
        elif s.rays == "with_params":
            rays = send.any(axis=1) | new
        else:
            rays = np.full(peers, s.rays == "always")
        spent = 1.0 - float(agent_feature(observation, "budget_left"))
        if step < s.start or spent > float(agent_feature(observation, "progress")) + s.slack:
            send[:], new[:], rays[:] = False, False, False
        return np.concatenate([send.reshape(-1), new, rays]).astype(np.int8)

    def __call__(self, observations: Mapping[str, Mapping[str, np.ndarray]], infos=None,
                 step: int = 0) -> dict[str, np.ndarray]:
        """Actions of every agent that has an observation."""
        if observations is None:
            raise ValueError("instance_novelty reads observations: call it with the env's observations")
        return {agent: self.act(obs, step) for agent, obs in observations.items()}
