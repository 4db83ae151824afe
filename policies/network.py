"""The learned communication policy's network, in plain torch (no RL library needed to run it).

``CommFeatures`` reads an observation (``openmulti_env.environment.layout``): a small CNN over the ``map``
planes, pooled to a fixed 4 x 4 so any map size gives the same features, and an MLP over the ``comm`` vector;
``CommPolicyNetwork`` adds the action head: one logit per action entry (send parameters / share rays per
peer; action form ``entries``), one per agent broadcast to all its entries (``round``: send everything
now or not, ``policies.gate``), or one for the whole team from its agents' pooled features (``team``: every
agent sends everything this round or none does), acted on as Bernoulli draws (training) or their mode, logit > 0.
The trainer wraps ``CommFeatures`` as Stable-Baselines3's features extractor, so the weights it learns
load here unchanged.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

from policies.gate import check_action_form, payload_rule


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
    """``entries`` (a logit per action entry), ``round`` (one logit per agent, broadcast) or ``team`` (one for the
    team); files written before the round form existed have no such key and are ``entries``."""
    link_inputs: int = 0
    """Values of the ``links`` observation read beside ``comm`` ((N - 1) x ``LINK_STATE``; 0: none, as every file
    written before the link scenarios)."""
    payload: str = "everything"
    """What the ``team`` form's 1 sends: ``everything`` or ``instance_novelty[:settings]`` (``policies.gate``)."""

    def __post_init__(self) -> None:
        check_action_form(self.action_form)
        if payload_rule(self.payload) is not None and self.action_form != "team":
            raise ValueError(f"payload {self.payload!r} gates the team form only, not {self.action_form!r}")

    @property
    def heads(self) -> int:
        """Logits of the action head."""
        return 1 if self.action_form in ("round", "team") else self.actions

    @property
    def head_inputs(self) -> int:
        """Inputs of the action head: one agent's features, or in the ``team`` form the team's pooled (mean, max)."""
        return 2 * self.features if self.action_form == "team" else self.features

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
        self.comm = nn.Sequential(nn.Linear(config.comm_size + config.link_inputs, config.comm_features), nn.ReLU())
        self.trunk = nn.Sequential(nn.Linear(config.map_features + config.comm_features, config.features), nn.ReLU())

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        comm = observations["comm"]
        if self.config.link_inputs:
            comm = torch.cat([comm, observations["links"].flatten(1)], dim=1)
        return self.trunk(torch.cat([self.cnn(observations["map"]), self.comm(comm)], dim=1))

    def observe(self, map_hwc: np.ndarray, comm: np.ndarray, links: np.ndarray | None = None) -> torch.Tensor:
        """Features of raw observations: ``map_hwc`` (B, H, W, C) uint8, ``comm`` (B, K) float, ``links``
        (B, N - 1, 2) float when the network reads them."""
        device = next(self.parameters()).device
        planes = torch.as_tensor(np.asarray(map_hwc), device=device).permute(0, 3, 1, 2).float() / 255.0
        parts = dict(map=planes, comm=torch.as_tensor(np.asarray(comm, np.float32), device=device))
        if self.config.link_inputs:
            if links is None:
                raise ValueError("this network reads the 'links' observation: pass it")
            parts["links"] = torch.as_tensor(np.asarray(links, np.float32), device=device)
        return self(parts)


class CommPolicyNetwork(nn.Module):
    """Features and the action head (``config.heads`` logits)."""

    def __init__(self, config: NetworkConfig):
        super().__init__()
        self.config = config
        self.features = CommFeatures(config)
        self.action = nn.Linear(config.head_inputs, config.heads)

    @torch.no_grad()
    def act(self, map_hwc: np.ndarray, comm: np.ndarray, rng: np.random.Generator | None = None,
            links: np.ndarray | None = None) -> np.ndarray:
        """(B, actions) int8: each Bernoulli head drawn with ``rng`` (the policy as trained), or its mode
        (logit > 0) when ``rng`` is None; a ``round`` head's draw is every entry of its agent; in the ``team`` form
        the batch is one team and one draw (or mode) is every entry of every agent."""
        features = self.features.observe(map_hwc, comm, links)
        if self.config.action_form == "team":  # the batch is one team: one decision for all of it
            logits = self.action(team_pool(features[None]))
            logits = logits.expand(len(features), -1)
            if rng is not None:  # one draw for the team, every agent acts on it
                draw = rng.random()
                return np.full((len(features), self.config.actions), int(draw < float(torch.sigmoid(logits[0, 0]))),
                               np.int8)
        else:
            logits = self.action(features)
        logits = logits.double().cpu().numpy()
        if rng is None:
            drawn = (logits > 0).astype(np.int8)
        else:
            drawn = (rng.random(logits.shape) < 0.5 * (1.0 + np.tanh(0.5 * logits))).astype(np.int8)  # sigmoid
        return np.repeat(drawn, self.config.actions, axis=1) if self.config.heads == 1 else drawn


    @torch.no_grad()
    def team_send_probability(self, map_hwc: np.ndarray, comm: np.ndarray, links: np.ndarray | None = None) -> float:
        """The ``team`` form's probability that the team sends this round (the batch is the team's agents)."""
        if self.config.action_form != "team":
            raise ValueError(f"a {self.config.action_form}-form network draws per agent or entry, not once for the team")
        return float(torch.sigmoid(self.action(team_pool(self.features.observe(map_hwc, comm, links)[None]))[0, 0]))


def team_pool(features: torch.Tensor) -> torch.Tensor:
    """(B, N, F) per-agent features -> (B, 2F): their mean and max over the team (any order, any team size)."""
    return torch.cat([features.mean(dim=1), features.amax(dim=1)], dim=1)
