"""The paper's scripted communication policies, as functions of what an env exposes (agent names,
their action length, their infos), so that the env and ``openmulti run`` drive the team the same way.

Action layout (DESIGN.md): ``MultiBinary(2 * (N - 1))`` per agent; the first N - 1 entries "send my
parameters to peer j", the last N - 1 "share my ray directions with peer j", peers in ascending index
order skipping the agent itself.

Policies by name: ``always``, ``never``, ``bernoulli:P`` (always, and the channel delivers each
message with probability P: the paper's communication-failure study), ``round_robin`` (each round
every agent talks to one peer, in turn) and ``budget`` (always, until the agent's byte budget is
spent: ``infos[agent]["budget_left_mb"]``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

SCRIPTED_POLICIES = ("always", "never", "round_robin", "budget")


class PolicyError(ValueError):
    """An unknown policy name or bad parameters."""


@dataclass(frozen=True)
class PolicySpec:
    """A parsed policy name: the scripted rule and the link success probability it implies."""

    name: str
    rule: str
    success_probability: float = 1.0


def parse_policy(name: str) -> PolicySpec:
    """``always``, ``never``, ``round_robin``, ``budget``, ``bernoulli:P`` (P in [0, 1]) or a file path."""
    if name in SCRIPTED_POLICIES:
        return PolicySpec(name, name)
    if name.startswith("bernoulli:"):
        try:
            p = float(name.split(":", 1)[1])
        except ValueError:
            p = -1.0
        if not 0.0 <= p <= 1.0:
            raise PolicyError(f"policy {name!r}: bernoulli:P needs a success probability P in [0, 1]")
        return PolicySpec(name, "always", p)
    if Path(name).is_file():
        return PolicySpec(name, "file")
    raise PolicyError(f"unknown policy {name!r}: use {', '.join(SCRIPTED_POLICIES)}, bernoulli:P or a trained "
                      "policy file")


class ScriptedPolicy:
    """Actions of a scripted rule for agents ``agent_0 .. agent_{N-1}``."""

    def __init__(self, spec: PolicySpec | str, num_agents: int):
        self.spec = parse_policy(spec) if isinstance(spec, str) else spec
        if self.spec.rule == "file":
            raise PolicyError(f"{self.spec.name}: trained policies are run through the PettingZoo env (openmulti "
                              "train / the env issue); openmulti run takes the scripted ones")
        if num_agents < 1:
            raise PolicyError("num_agents must be >= 1")
        self.num_agents = num_agents

    def __call__(self, infos: Mapping[str, Mapping[str, float]] | None, step: int) -> dict[str, np.ndarray]:
        """One action (2 * (N - 1),) int8 per agent for round ``step``."""
        n, rule = self.num_agents, self.spec.rule
        width = max(n - 1, 0)
        out = {}
        for i in range(n):
            name = f"agent_{i}"
            if rule == "never" or width == 0:
                half = np.zeros(width, np.int8)
            elif rule == "round_robin":
                half = np.zeros(width, np.int8)
                half[step % width] = 1
            elif rule == "budget":
                left = float((infos or {}).get(name, {}).get("budget_left_mb", float("inf")))
                half = np.full(width, 1 if left > 0 else 0, np.int8)
            else:  # always
                half = np.ones(width, np.int8)
            out[name] = np.concatenate([half, half])
        return out
