"""The communication policy as an RLlib ``RLModule``: the same network as ``policies.network``, so what RLlib
learns exports unchanged to the package's policy files.

``CommRLModule`` holds ``features`` (``CommFeatures``) and ``action`` (one logit per action entry) under the
same names as ``CommPolicyNetwork``, plus a value head on the shared features (SB3's ``vf=[64]``). Its actions
are independent Bernoulli entries (``BernoulliEntries``), the distribution SB3 uses for ``MultiBinary``:
RLlib's new API stack has no default distribution for ``MultiBinary``, and a ``MultiDiscrete`` of twos
would double the logits and break the export. Ray is imported only here.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

import gymnasium as gym
import torch
from ray.rllib.core.columns import Columns
from ray.rllib.core.distribution.torch.torch_distribution import TorchDeterministic, TorchDistribution
from ray.rllib.core.rl_module.apis import ValueFunctionAPI
from ray.rllib.core.rl_module.torch import TorchRLModule
from torch import nn

from policies.network import CommFeatures, CommPolicyNetwork, NetworkConfig


class BernoulliEntries(TorchDistribution):
    """Independent Bernoulli draws, one per action entry; log-probability and entropy summed over entries."""

    def __init__(self, logits: torch.Tensor):
        self.logits = logits
        super().__init__(logits=logits)

    def _get_torch_distribution(self, logits: torch.Tensor) -> torch.distributions.Distribution:
        return torch.distributions.Independent(torch.distributions.Bernoulli(logits=logits, validate_args=False), 1)

    @staticmethod
    def required_input_dim(space: gym.Space, **kwargs) -> int:
        return int(space.n)

    def to_deterministic(self) -> TorchDeterministic:
        """The mode, logit > 0: what a deployed policy does (``CommPolicyNetwork.act`` without a generator)."""
        return TorchDeterministic(loc=(self.logits > 0).to(self.logits.dtype))


def network_config(model_config: dict) -> NetworkConfig:
    """The ``NetworkConfig`` in an RLModule's ``model_config`` (RLlib adds its own default keys to it)."""
    names = {f.name for f in fields(NetworkConfig)}
    return NetworkConfig.from_dict({k: v for k, v in model_config.items() if k in names})


class CommRLModule(TorchRLModule, ValueFunctionAPI):
    """``CommFeatures`` -> action logits and a value. ``model_config`` is a ``NetworkConfig.as_dict()``.

    Observations arrive as RLlib batches them: ``{"map": (B, H, W, C) uint8-valued, "comm": (B, K)}``."""

    def setup(self) -> None:
        config = network_config(self.model_config)
        if config.actions != int(self.action_space.n):
            raise ValueError(f"the policy has {config.actions} action entries but the env's action space is "
                             f"{self.action_space}")
        self.features = CommFeatures(config)
        self.action = nn.Linear(config.features, config.actions)
        self.value = nn.Sequential(nn.Linear(config.features, 64), nn.Tanh(), nn.Linear(64, 1))
        self.action_dist_cls = BernoulliEntries

    def _embed(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        planes = observations["map"].permute(0, 3, 1, 2).float() / 255.0
        return self.features(dict(map=planes, comm=observations["comm"].float()))

    def _forward(self, batch: dict[str, Any], **kwargs) -> dict[str, Any]:
        return {Columns.ACTION_DIST_INPUTS: self.action(self._embed(batch[Columns.OBS]))}

    def _forward_train(self, batch: dict[str, Any], **kwargs) -> dict[str, Any]:
        embeddings = self._embed(batch[Columns.OBS])
        return {Columns.ACTION_DIST_INPUTS: self.action(embeddings), Columns.EMBEDDINGS: embeddings}

    def compute_values(self, batch: dict[str, Any], embeddings: Any = None) -> torch.Tensor:
        if embeddings is None:
            embeddings = self._embed(batch[Columns.OBS])
        return self.value(embeddings).squeeze(-1)


def export_module(module: CommRLModule) -> CommPolicyNetwork:
    """The trained module's policy (features and action head, no value head) as a ``CommPolicyNetwork``."""
    network = CommPolicyNetwork(network_config(module.model_config))
    network.features.load_state_dict(module.features.state_dict())
    network.action.load_state_dict(module.action.state_dict())
    return network.eval()
