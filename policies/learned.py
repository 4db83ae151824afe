"""A trained communication policy: ``--policy learned`` (the one shipped in ``policies/trained/``) or a file.

Acts on every agent's observation with one shared network (parameter sharing, as it was trained), drawing
each action entry from its Bernoulli with a seeded generator: the policy PPO trained. Its mode (logit > 0,
``learned:mode``) is another policy: a network that learned to send each entry a third of the time has the
mode "never send". A ``team`` network with an ``instance_novelty`` payload decides when the team sends and the rule
what (the env in the ``instances`` action form, ``action_form`` below).
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from policies.files import load_policy
from policies.gate import payload_rule
from policies.scripted import PolicyError

SHIPPED = Path(__file__).parent / "trained" / "learned.json"
"""The best policy trained so far; ``policies/trained/README.md`` records the command that made it."""


class LearnedPolicy:
    """A policy file's network acting for every agent."""

    reads_observations = True

    def __init__(self, network, record: dict, source: str, seed: int | None = 0):
        self.network, self.record, self.source = network, record, source
        self.rng = None if seed is None else np.random.default_rng(seed)
        self.rule = payload_rule(network.config.payload)
        self.action_form = "entries" if self.rule is None else "instances"
        """The env's action form this policy acts in (runners build the env with it)."""

    @staticmethod
    def load(name: str, num_agents: int, seed: int | None = 0) -> "LearnedPolicy":
        """``learned`` or a path (PolicyError when the file is missing or does not fit); ``seed`` drives the
        draws (None: the mode of each entry)."""
        path = SHIPPED if name == "learned" else Path(name)
        if name == "learned" and not SHIPPED.is_file():
            raise PolicyError("no trained policy ships with this version yet (policies/trained/learned.json); train "
                              "one with `openmulti train` and pass its file to --policy")
        network, record = load_policy(path, num_agents)
        return LearnedPolicy(network, record, str(path), seed)

    def __call__(self, observations: Mapping[str, Mapping[str, np.ndarray]], infos=None,
                 step: int = 0) -> dict[str, np.ndarray]:
        agents = list(observations or {})
        maps, comms, links = self.inputs(observations)
        actions = self.network.act(maps, comms, self.rng, links)
        if self.rule is not None:  # the team's decision gates what the rule picks for each agent
            picked = self.rule(observations, None, step)
            return {a: picked[a] * np.int8(actions[0, 0]) for a in agents}
        return {a: actions[k] for k, a in enumerate(agents)}

    def inputs(self, observations: Mapping[str, Mapping[str, np.ndarray]]):
        """The network's inputs stacked over the agents: maps (N, H, W, C), comm (N, K), links (N, N - 1, L) or None;
        PolicyError when they do not fit the network."""
        if observations is None:
            raise ValueError("a learned policy reads observations: call it with the env's observations")
        agents = list(observations)
        maps = np.stack([np.asarray(observations[a]["map"]) for a in agents])
        comms = np.stack([np.asarray(observations[a]["comm"], np.float32) for a in agents])
        config = self.network.config
        if maps.shape[-1] != config.map_channels or comms.shape[-1] != config.comm_size:
            raise PolicyError(f"{self.source} takes maps of {config.map_channels} channels and comm vectors of "
                              f"{config.comm_size}; the env gives {maps.shape[-1]} and {comms.shape[-1]}")
        links = None
        if config.link_inputs:
            if any("links" not in observations[a] for a in agents):
                raise PolicyError(f"{self.source} reads the 'links' observation, which these observations lack")
            links = np.stack([np.asarray(observations[a]["links"], np.float32) for a in agents])
            if links[0].size != config.link_inputs:
                raise PolicyError(f"{self.source} reads {config.link_inputs} link values; the env gives {links[0].size}")
        return maps, comms, links
