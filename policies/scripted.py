"""Scripted communication policies and policy names.

Action layout (DESIGN.md): ``MultiBinary(2 * (N - 1))`` per agent; the first N - 1 entries "send my
parameters to peer j", the last N - 1 "share my ray directions with peer j", peers in ascending index
order skipping the agent itself.

Every policy is called as ``policy(observations, infos, step) -> {agent: action}``
(``openmulti_env.environment.layout`` for what an observation holds); the fixed schedules here ignore the
observations:

- ``always`` / ``never``;
- ``round_robin``: each round every agent talks to one peer, in turn;
- ``budget``: always, until the agent's byte budget is spent (``infos[agent]["budget_left_mb"]``);
- ``every:K``: everything to every peer on every K-th round (rounds 0, K, 2K, ...), nothing between;
- ``at:R1,R2,...``: everything to every peer on the listed rounds (0-based), nothing on the others: any
  timing of whole rounds (``every:3`` on 12 rounds is ``at:0,3,6,9``);
- ``rate:Q``: each entry of each action 1 with probability Q (seeded), the fixed-rate baseline a
  schedule must beat at equal bytes;
- ``bernoulli:P``: is not a schedule but a channel: ``always``, with each message arriving with
  probability P (the paper's communication-failure study); it spends ``always``'s bytes.

``novelty[:settings]`` (``policies.novelty``) and ``instance_novelty[:settings]`` (``policies.instance_novelty``,
on the ``instances`` action form: which instances go to which peer) read observations; ``learned`` and a file path
are trained policies (``policies.learned``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

SCRIPTED_POLICIES = ("always", "never", "round_robin", "budget")
POLICY_FORMS = "always, never, round_robin, budget, every:K, at:R1,R2,..., rate:Q, bernoulli:P, novelty[:settings], " \
               "instance_novelty[:settings], learned or a trained policy file (either with :mode for the deterministic mode of each entry)"


class PolicyError(ValueError):
    """An unknown policy name, bad settings, or a policy file that does not fit."""


@dataclass(frozen=True)
class PolicySpec:
    """A parsed policy name: its rule, the rule's settings and the link success probability it implies."""

    name: str
    rule: str
    """always, never, round_robin, budget, every, at, rate, novelty, instance_novelty, learned or file."""
    success_probability: float = 1.0
    settings: dict = field(default_factory=dict)


def _number(name: str, text: str, kind, low: float, high: float, what: str):
    try:
        value = kind(text)
    except ValueError:
        value = None
    if value is None or not low <= value <= high:
        raise PolicyError(f"policy {name!r}: {what}")
    return value


def parse_policy(name: str) -> PolicySpec:
    """A policy name (``POLICY_FORMS``) as a spec; PolicyError naming the problem otherwise."""
    if name in SCRIPTED_POLICIES:
        return PolicySpec(name, name)
    head, _, arg = name.partition(":")
    if head == "bernoulli" and arg:
        return PolicySpec(name, "always", _number(name, arg, float, 0.0, 1.0,
                                                  "bernoulli:P needs a success probability P in [0, 1]"))
    if head == "every" and arg:
        return PolicySpec(name, "every", settings={"k": _number(name, arg, int, 1, 10**6,
                                                                 "every:K needs a whole number of rounds K >= 1")})
    if head == "at" and arg:
        rounds = tuple(sorted({_number(name, r.strip(), int, 0, 10**6, "at:R1,R2,... needs rounds as whole numbers >= 0 "
                                                                   "separated by commas") for r in arg.split(",")}))
        return PolicySpec(name, "at", settings={"rounds": rounds})
    if head == "rate" and arg:
        return PolicySpec(name, "rate", settings={"q": _number(name, arg, float, 0.0, 1.0,
                                                                "rate:Q needs a probability Q in [0, 1]")})
    if head in ("novelty", "instance_novelty"):  # observation-reading heuristics with name=value settings
        if head == "novelty":
            from policies.novelty import NoveltySettings as Settings  # noqa: PLC0415
        else:
            from policies.instance_novelty import InstanceNoveltySettings as Settings  # noqa: PLC0415
        try:
            settings = Settings.parse(arg)
        except ValueError as exc:
            raise PolicyError(f"policy {name!r}: {exc}") from None
        return PolicySpec(name, head, settings={head: settings})
    base, mode = (name[:-len(":mode")], "mode") if name.endswith(":mode") else (name, "sample")
    if base == "learned":
        return PolicySpec(name, "learned", settings={"path": "learned", "act": mode})
    if Path(base).is_file():
        return PolicySpec(name, "file", settings={"path": base, "act": mode})
    if base.endswith((".json", ".safetensors")) or "/" in base:
        raise PolicyError(f"policy file {base!r} does not exist")
    raise PolicyError(f"unknown policy {name!r}: use {POLICY_FORMS}")


class ScriptedPolicy:
    """Actions of a fixed schedule for agents ``agent_0 .. agent_{N-1}`` (``seed`` drives ``rate:Q``)."""

    reads_observations = False

    def __init__(self, spec: PolicySpec | str, num_agents: int, seed: int = 0):
        self.spec = parse_policy(spec) if isinstance(spec, str) else spec
        if self.spec.rule not in SCRIPTED_POLICIES + ("every", "at", "rate"):
            raise PolicyError(f"{self.spec.name} is not a fixed schedule; make it with policies.make_policy")
        if num_agents < 1:
            raise PolicyError("num_agents must be >= 1")
        self.num_agents = num_agents
        self.rng = np.random.default_rng([seed, 0x5C4ED])

    def __call__(self, observations: Mapping | None, infos: Mapping[str, Mapping[str, float]] | None,
                 step: int) -> dict[str, np.ndarray]:
        """One action (2 * (N - 1),) int8 per agent for round ``step``."""
        n, rule = self.num_agents, self.spec.rule
        width = max(n - 1, 0)
        out = {}
        for i in range(n):
            name = f"agent_{i}"
            if rule == "rate":
                out[name] = (self.rng.random(2 * width) < self.spec.settings["q"]).astype(np.int8)
                continue
            if rule == "never" or width == 0:
                half = np.zeros(width, np.int8)
            elif rule == "round_robin":
                half = np.zeros(width, np.int8)
                half[step % width] = 1
            elif rule == "budget":
                left = float((infos or {}).get(name, {}).get("budget_left_mb", float("inf")))
                half = np.full(width, 1 if left > 0 else 0, np.int8)
            elif rule == "every":
                half = np.full(width, 1 if step % self.spec.settings["k"] == 0 else 0, np.int8)
            elif rule == "at":
                half = np.full(width, 1 if step in self.spec.settings["rounds"] else 0, np.int8)
            else:  # always
                half = np.ones(width, np.int8)
            out[name] = np.concatenate([half, half])
        return out
