"""The learned communication policy's network, in plain torch (no RL library needed to run it).

``CommFeatures`` reads an observation (``policies.observation``): a small CNN over the ``map`` planes,
pooled to a fixed 4 x 4 so any map size gives the same features, and an MLP over the ``comm`` vector;
``CommPolicyNetwork`` adds the action head: one logit per action entry (send parameters / share rays per
peer; action form ``entries``) or one per agent broadcast to all its entries (``round``: send everything
now or not, ``policies.gate``), acted on as Bernoulli draws (training) or their mode, logit > 0.
The trainer wraps ``CommFeatures`` as Stable-Baselines3's features extractor, so the weights it learns
load here unchanged.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

from policies.gate import check_action_form


@dataclass(frozen=True)
class NetworkConfig:
    """The architecture, written beside the weights (a policy file's JSON)."""

    map_channels: int
    comm_size: int
    actions: int
    conv_channels: tuple[int, int, int] = (16, 32, 32)
    map_features: int = 128
    comm_features: int = 64
    features: int = 128
    action_form: str = "entries"
    """``entries`` (a logit per action entry) or ``round`` (one logit, broadcast); files written before the
    round form existed have no such key and are ``entries``."""

    def __post_init__(self) -> None:
        check_action_form(self.action_form)

    @property
    def heads(self) -> int:
        """Logits of the action head."""
        return 1 if self.action_form == "round" else self.actions

    def as_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @staticmethod
    def from_dict(data: dict) -> "NetworkConfig":
        values = dict(data)
        values["conv_channels"] = tuple(values["conv_channels"])
        return NetworkConfig(**values)


class CommFeatures(nn.Module):
    """Observation -> (B, ``features``) features. ``forward`` takes the map as (B, C, H, W) floats in [0, 1]
    (what SB3 hands its extractors); ``observe`` takes raw observations (uint8 (B, H, W, C) maps)."""

    def __init__(self, config: NetworkConfig):
        super().__init__()
        c1, c2, c3 = config.conv_channels
        self.config = config
        self.cnn = nn.Sequential(
            nn.Conv2d(config.map_channels, c1, 5, stride=2, padding=2), nn.ReLU(),
            nn.Conv2d(c1, c2, 3, stride=2, padding=1), nn.ReLU(),
            nn.Conv2d(c2, c3, 3, stride=2, padding=1), nn.ReLU(),
            nn.AdaptiveAvgPool2d(4), nn.Flatten(), nn.Linear(c3 * 16, config.map_features), nn.ReLU())
        self.comm = nn.Sequential(nn.Linear(config.comm_size, config.comm_features), nn.ReLU())
        self.trunk = nn.Sequential(nn.Linear(config.map_features + config.comm_features, config.features), nn.ReLU())

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.trunk(torch.cat([self.cnn(observations["map"]), self.comm(observations["comm"])], dim=1))

    def observe(self, map_hwc: np.ndarray, comm: np.ndarray) -> torch.Tensor:
        """Features of raw observations: ``map_hwc`` (B, H, W, C) uint8, ``comm`` (B, K) float."""
        device = next(self.parameters()).device
        planes = torch.as_tensor(np.asarray(map_hwc), device=device).permute(0, 3, 1, 2).float() / 255.0
        return self(dict(map=planes, comm=torch.as_tensor(np.asarray(comm, np.float32), device=device)))


class CommPolicyNetwork(nn.Module):
    """Features and the action head (``config.heads`` logits)."""

    def __init__(self, config: NetworkConfig):
        super().__init__()
        self.config = config
        self.features = CommFeatures(config)
        self.action = nn.Linear(config.features, config.heads)

    @torch.no_grad()
    def act(self, map_hwc: np.ndarray, comm: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """(B, actions) int8: each Bernoulli head drawn with ``rng`` (the policy as trained), or its mode
        (logit > 0) when ``rng`` is None; a ``round`` head's draw is every entry of its agent."""
        logits = self.action(self.features.observe(map_hwc, comm)).double().cpu().numpy()
        if rng is None:
            drawn = (logits > 0).astype(np.int8)
        else:
            drawn = (rng.random(logits.shape) < 0.5 * (1.0 + np.tanh(0.5 * logits))).astype(np.int8)  # sigmoid
        return np.repeat(drawn, self.config.actions, axis=1) if self.config.action_form == "round" else drawn
