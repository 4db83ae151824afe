"""A centralised critic (MAPPO's recipe) for the shared decentralised policy: the actor reads the agent's own
observation, the value function reads ``state()`` too (every agent's map and the ground-truth coverage behind
the reward), during training only.

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
``state()`` and the agent's ``comm`` (MAPPO)."""


def check_critic(critic: str) -> str:
    """``critic`` if known; ValueError naming the known ones otherwise."""
    if critic not in CRITICS:
        raise ValueError(f"unknown critic {critic!r}: use one of {', '.join(CRITICS)}")
    return critic


class WithState(BaseParallelWrapper):
    """The wrapped env with ``state`` (its ``state()``) added to every agent's observation."""

    def __init__(self, env):
        super().__init__(env)
        if not hasattr(env, "state_space"):
            raise ValueError(f"a central critic reads state(): {type(env).__name__} has no state_space")
        inner = env.observation_space(env.possible_agents[0])
        self._space = spaces.Dict({**inner.spaces, "state": env.state_space})

    def observation_space(self, agent):
        self.env.observation_space(agent)  # names an unknown agent
        return self._space

    def _with_state(self, observations: dict) -> dict:
        if not observations:
            return observations
        state = np.asarray(self.env.state())
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
    """The critic's features: a CNN over ``state`` (B, C, H, W) in [0, 1] and an MLP over the agent's ``comm``
    (in the team form (B, N, K), flattened), to ``features``."""

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
        comm = observations["comm"].flatten(1)
        return self.trunk(torch.cat([self.cnn(observations["state"]), self.comm(comm)], dim=1))


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
            state = observation_space.spaces["state"]
            channels = state.shape[0] if state.shape[0] < state.shape[-1] else state.shape[-1]  # SB3 moves channels first
            comm = int(np.prod(observation_space.spaces["comm"].shape))
            self.vf_features_extractor = StateFeatures(channels, comm, self.features_dim)
            self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    return CentralCriticPolicy
