"""A centralised critic (MAPPO's recipe) for the shared decentralised policy: the actor reads the agent's own
observation, the value function reads ``state()`` (every agent's map and the ground-truth coverage behind the
reward) and the agent's ``comm``, during training only.

Why SB3 with a critic of our own rather than TorchRL's or RLlib's multi-agent PPO: the trainer, its worker
processes, checkpoints, policy files and logs are SB3's already, and MAPPO's difference from parameter-shared
PPO is only what the value function reads. ``WithState`` puts ``state`` into every agent's observation (the
actor's features never look at it), and ``central_critic_policy`` gives SB3 a policy whose value function has
its own extractor over ``state`` and the agent's ``comm``. TorchRL's MAPPO needs BenchMARL, which does not
import with the TorchRL here; RLlib pins an older Gymnasium and is this package's cluster backend.
"""

from __future__ import annotations

import numpy as np
import torch
from gymnasium import spaces
from pettingzoo.utils.wrappers import BaseParallelWrapper
from torch import nn

CRITICS = ("local", "central")
"""``local``: the value function reads what the actor reads (parameter-shared PPO); ``central``: it reads
``state()`` and the agent's ``comm`` (MAPPO; with the team reward every agent's value is the team's, so the
critic needs no agent identity: with ``reward="individual"`` it would)."""


def check_critic(critic: str) -> str:
    """``critic`` if known; ValueError naming the known ones otherwise."""
    if critic not in CRITICS:
        raise ValueError(f"unknown critic {critic!r}: use one of {', '.join(CRITICS)}")
    return critic


class WithState(BaseParallelWrapper):
    """The wrapped env with ``state`` added to every agent's observation, as (N, S, S, C) planes per agent: its
    ``state()`` (S, S, C N) split by agent. Four axes on purpose: SB3 takes a 3-axis uint8 box for an image and
    guesses its channel axis from the smallest side, which picks the wrong one once C N >= S (7 agents at 48)."""

    def __init__(self, env):
        super().__init__(env)
        if not hasattr(env, "state_space"):
            raise ValueError(f"a central critic reads state(): {type(env).__name__} has no state_space")
        inner = env.observation_space(env.possible_agents[0])
        height, width, channels = env.state_space.shape
        self.agents_n = len(env.possible_agents)
        if channels % self.agents_n:
            raise ValueError(f"state() has {channels} planes, not a whole number per agent of {self.agents_n}")
        shape = (self.agents_n, height, width, channels // self.agents_n)
        self._space = spaces.Dict({**inner.spaces, "state": spaces.Box(0, 255, shape, np.uint8)})

    def observation_space(self, agent):
        self.env.observation_space(agent)  # names an unknown agent
        return self._space

    def _with_state(self, observations: dict) -> dict:
        if not observations:
            return observations
        flat = np.asarray(self.env.state())
        state = np.ascontiguousarray(flat.reshape(*flat.shape[:2], self.agents_n, -1).transpose(2, 0, 1, 3))
        return {agent: {**obs, "state": state} for agent, obs in observations.items()}

    def reset(self, seed: int | None = None, options: dict | None = None):
        observations, infos = self.env.reset(seed=seed, options=options)
        return self._with_state(observations), infos

    def step(self, actions):
        observations, rewards, terminations, truncations, infos = self.env.step(actions)
        return self._with_state(observations), rewards, terminations, truncations, infos


class StateFactory:
    """Picklable: ``WithState(env_factory(index))``."""

    def __init__(self, env_factory):
        self.env_factory = env_factory

    def __call__(self, index: int) -> WithState:
        return WithState(self.env_factory(index))


class StateFeatures(nn.Module):
    """The critic's features: a CNN over ``state`` ((B, N, S, S, C) floats in [0, 255], every agent's planes as
    channels) and an MLP over the agent's ``comm`` (in the team form (B, N, K), flattened), to ``features``."""

    def __init__(self, state_channels: int, comm_size: int, features: int = 128):
        super().__init__()
        self.cnn = nn.Sequential(
            nn.Conv2d(state_channels, 32, 5, stride=2, padding=2), nn.ReLU(),
            nn.Conv2d(32, 32, 3, stride=2, padding=1), nn.ReLU(),
            nn.Conv2d(32, 32, 3, stride=2, padding=1), nn.ReLU(),
            nn.AdaptiveAvgPool2d(4), nn.Flatten(), nn.Linear(32 * 16, features), nn.ReLU())
        self.comm = nn.Sequential(nn.Linear(comm_size, 64), nn.ReLU())
        self.trunk = nn.Sequential(nn.Linear(features + 64, features), nn.ReLU())

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        state = observations["state"]  # (B, N, S, S, C): agent-major planes, as state() orders them
        planes = state.permute(0, 2, 3, 1, 4).flatten(3).permute(0, 3, 1, 2) / 255.0
        comm = observations["comm"].flatten(1)
        return self.trunk(torch.cat([self.cnn(planes), self.comm(comm)], dim=1))


def central_critic_policy():
    """SB3's ``MultiInputActorCriticPolicy`` with the value function's extractor replaced by ``StateFeatures``
    (SB3 imported only when training). It takes ``share_features_extractor=False``."""
    from stable_baselines3.common.policies import MultiInputActorCriticPolicy  # noqa: PLC0415

    class CentralCriticPolicy(MultiInputActorCriticPolicy):
        def __init__(self, observation_space, action_space, lr_schedule, **kwargs):
            if "state" not in observation_space.spaces:
                raise ValueError("a central critic reads 'state': wrap the env in policies.critic.WithState")
            kwargs["share_features_extractor"] = False
            super().__init__(observation_space, action_space, lr_schedule, **kwargs)
            agents, _, _, planes = observation_space.spaces["state"].shape  # WithState's (N, S, S, C)
            comm = int(np.prod(observation_space.spaces["comm"].shape))
            self.vf_features_extractor = StateFeatures(agents * planes, comm, self.features_dim)
            self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    return CentralCriticPolicy
