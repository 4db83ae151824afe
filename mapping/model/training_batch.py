"""One bank's part of an agent's training step, apart from the agent so that a fleet
(``mapping.model.fleet``) can evaluate every agent's batches in one computation."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from mapping.model.keyframes import InstanceRays
from mapping.model.render import RaySamples


@dataclass
class TrainingBatch:
    """One bank's part of a training step: the sampled keyframe rays of its trainable instances
    (``rows``, (N,)) and the samples along them inside each instance's box."""

    bank: str
    rows: torch.Tensor
    rays: InstanceRays
    samples: RaySamples
    near: torch.Tensor
    far: torch.Tensor
    """(N, R) where each ray enters and leaves its instance's box (clamped to the camera)."""

    @property
    def positions(self) -> torch.Tensor:
        """(N, R * S, 3) world points the field is evaluated on."""
        n, r, s = self.samples.depths.shape
        return self.samples.positions.reshape(n, r * s, 3)
