"""The ``round`` action form: one decision per agent and round, "send everything to every peer now or not".

The env's action is ``MultiBinary(2 * (N - 1))`` (parameters and rays per peer). Drawn as independent
Bernoulli entries, a policy that sends a third of the time spreads its messages over rounds like random
links (``rate:Q``), while at equal bytes whole rounds every K steps (``every:K``) complete more
(docs/schedules.md). ``RoundGate`` gives an RL library an env whose action is one entry per agent and
broadcasts it to every entry of the wrapped env, so a policy learns when to talk, not to whom.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from gymnasium import spaces
from pettingzoo.utils.wrappers import BaseParallelWrapper

ACTION_FORMS = ("entries", "round")
"""``entries``: one Bernoulli per action entry; ``round``: one per agent, broadcast to all its entries."""


def check_action_form(form: str) -> str:
    """``form`` if it is one of ``ACTION_FORMS``; ValueError naming the known ones otherwise."""
    if form == "instances":
        raise ValueError("the instances action form is not trained here: `openmulti train` trains the entries and round "
                         "forms; drive the instances form with instance_novelty, or with a trainer of your own on "
                         "parallel_env(action_form='instances') (its observation adds the per-slot 'instances' entry)")
    if form not in ACTION_FORMS:
        raise ValueError(f"unknown action form {form!r}: use one of {', '.join(ACTION_FORMS)}")
    return form


class RoundGate(BaseParallelWrapper):
    """A ParallelEnv whose agents act with ``MultiBinary(1)``: 1 sends on every entry of the wrapped action."""

    def __init__(self, env):
        super().__init__(env)
        self.entries = {agent: int(env.action_space(agent).n) for agent in env.possible_agents}
        self.gate = spaces.MultiBinary(1)

    def action_space(self, agent):
        self.env.action_space(agent)  # names an unknown agent
        return self.gate

    def step(self, actions):
        wide = {}
        for agent, action in actions.items():
            value = np.asarray(action).reshape(-1)
            if value.size != 1:
                raise ValueError(f"{agent}: a round-form action is one entry (send all or nothing), got {value.size}")
            wide[agent] = np.full(self.entries[agent], 1 if value[0] > 0.5 else 0, np.int8)
        return self.env.step(wide)


class GatedFactory:
    """Picklable: ``RoundGate(env_factory(index))`` (worker processes build their env from it)."""

    def __init__(self, env_factory: Callable[[int], object]):
        self.env_factory = env_factory

    def __call__(self, index: int) -> RoundGate:
        return RoundGate(self.env_factory(index))
