"""The ``round`` and ``team`` action forms: one decision per agent and round ("send everything to every peer
now or not"), or one for the whole team.

The env's action is ``MultiBinary(2 * (N - 1))`` (parameters and rays per peer). Drawn as independent
Bernoulli entries, a policy that sends a third of the time spreads its messages over rounds like random
links (``rate:Q``), while at equal bytes whole rounds every K steps (``every:K``) complete more
(docs/schedules.md). ``RoundGate`` gives an RL library an env whose action is one entry per agent and
broadcasts it to every entry of the wrapped env, so a policy learns when to talk, not to whom. ``TeamGate``
makes the team one agent that decides once a round for everyone (the timing study's whole rounds, chosen from
every agent's observation). What a 1 sends is the gate's ``payload``: ``everything`` (every entry of every agent), or
``instance_novelty`` (each agent sends what that rule picks this round: the instances a peer lacks or whose copy
there went stale; the env in the ``instances`` action form), so that the policy learns *when* and the rule says
*what*.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils.wrappers import BaseParallelWrapper

from policies.instance_novelty import InstanceNoveltyPolicy, InstanceNoveltySettings

ACTION_FORMS = ("entries", "round", "team")
"""``entries``: one Bernoulli per action entry; ``round``: one per agent, broadcast to all its entries; ``team``:
one for the whole team, from every agent's observation (``TeamGate``)."""


PAYLOADS = ("everything", "instance_novelty")
"""What a team decision of 1 sends: every entry of every agent, or ``instance_novelty``'s choice (settings after a
colon, ``instance_novelty:change=0.1``)."""


def payload_rule(payload: str) -> InstanceNoveltyPolicy | None:
    """The rule that picks what a 1 sends (None: everything); ValueError naming the known payloads."""
    name, _, settings = payload.partition(":")
    if name == "everything" and not settings:
        return None
    if name == "instance_novelty":
        return InstanceNoveltyPolicy(InstanceNoveltySettings.parse(settings))
    raise ValueError(f"unknown payload {payload!r}: use one of {', '.join(PAYLOADS)} (instance_novelty takes its "
                     "settings after a colon)")


def check_action_form(form: str) -> str:
    """``form`` if it is one of ``ACTION_FORMS``; ValueError naming the known ones otherwise."""
    if form == "instances":
        raise ValueError("the instances action form is not trained here: `openmulti train` trains the entries, round and "
                         "team forms; drive the instances form with instance_novelty, or with a trainer of your own on "
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


class TeamGate(ParallelEnv):
    """The team as one agent, ``team``: it reads every agent's ``map``, ``comm`` and ``links`` stacked (agents first; and
    ``state`` when the wrapped env's observations carry it, ``policies.critic.WithState``) and acts once a round
    with ``MultiBinary(1)``: 1 sends the ``payload`` (everything on every entry of every agent, or what
    ``instance_novelty`` picks for each agent this round), 0 nothing. Its reward is the
    agents' mean (with ``reward="team"`` the team reward every agent gets). Deciding for the team needs each agent's observation in
    one place: a coordinator that hears a few hundred bytes from each agent a round, which this env does not
    count (a parameter message is tens of kilobytes per instance)."""

    AGENT = "team"
    READS = ("map", "comm", "links", "state")

    def __init__(self, env, payload: str = "everything"):
        self.env = env
        self.rule = payload_rule(payload)
        self.possible_agents = [self.AGENT]
        self.metadata = dict(getattr(env, "metadata", {}), name="openmulti_team_gate")
        self.render_mode = None
        members = env.possible_agents
        self.entries = {agent: int(env.action_space(agent).n) for agent in members}
        space = env.observation_space(members[0])
        if self.rule is not None and "instances" not in space.spaces:
            raise ValueError(f"payload {payload!r} acts on the instances action form: build the env with "
                             "parallel_env(action_form='instances')")
        self._observations: dict = {}
        self._round = 0
        parts = {}
        for key in self.READS:
            if key not in space.spaces:
                continue
            sub = space.spaces[key]
            if key == "state":
                parts[key] = sub
            else:
                parts[key] = spaces.Box(float(np.min(sub.low)), float(np.max(sub.high)), (len(members),) + sub.shape,
                                        sub.dtype)
        self.observation_spaces = {self.AGENT: spaces.Dict(parts)}
        self.action_spaces = {self.AGENT: spaces.MultiBinary(1)}

    @property
    def agents(self) -> list[str]:
        return [self.AGENT] if self.env.agents else []

    def observation_space(self, agent):
        self._check(agent)
        return self.observation_spaces[self.AGENT]

    def action_space(self, agent):
        self._check(agent)
        return self.action_spaces[self.AGENT]

    def _check(self, agent) -> None:
        if agent != self.AGENT:
            raise KeyError(f"unknown agent {agent!r}: the team gate has one agent, {self.AGENT!r}")

    def _stack(self, observations: dict) -> dict:
        members = list(observations)
        out = {key: np.stack([np.asarray(observations[a][key]) for a in members])
               for key in self.observation_spaces[self.AGENT].spaces if key != "state"}
        if "state" in self.observation_spaces[self.AGENT].spaces:
            out["state"] = np.asarray(observations[members[0]]["state"])
        return {self.AGENT: out}

    def reset(self, seed: int | None = None, options: dict | None = None):
        observations, infos = self.env.reset(seed=seed, options=options)
        self._observations, self._round = observations, 0
        return self._stack(observations), {self.AGENT: next(iter(infos.values()))}

    def step(self, actions):
        value = np.asarray(actions[self.AGENT]).reshape(-1)
        if value.size != 1:
            raise ValueError(f"a team-form action is one entry (the whole team sends or not), got {value.size}")
        send = 1 if value[0] > 0.5 else 0
        if self.rule is not None and send:  # what the rule picks for each agent from its own observation
            wide = self.rule({a: self._observations[a] for a in self.env.agents}, None, self._round)
        else:
            wide = {agent: np.full(self.entries[agent], send, np.int8) for agent in self.env.agents}
        observations, rewards, terminations, truncations, infos = self.env.step(wide)
        self._observations, self._round = observations, self._round + 1
        team = self.AGENT
        return (self._stack(observations), {team: float(np.mean(list(rewards.values())))},
                {team: bool(all(terminations.values()))}, {team: bool(all(truncations.values()))},
                {team: next(iter(infos.values()))})

    def state(self):
        return self.env.state()

    def close(self) -> None:
        self.env.close()


class TeamFactory:
    """Picklable: ``TeamGate(env_factory(index), payload)``."""

    def __init__(self, env_factory: Callable[[int], object], payload: str = "everything"):
        self.env_factory, self.payload = env_factory, payload

    def __call__(self, index: int) -> TeamGate:
        return TeamGate(self.env_factory(index), self.payload)
