"""What an agent records about each of its instances, and what agents exchange about one.

``InstanceSlot`` is an agent's own bookkeeping (bank, row, box); ``InstanceFrame`` and
``ExportedInstance`` cross between agents (``mapping.team``), so they live apart from the agent that
makes them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mapping.model.bounds import InstanceBound
from mapping.model.observed import ObservedSpace


@dataclass
class InstanceSlot:
    """Where one instance id lives in an agent's map: its bank and row, its box, its frame's provenance."""

    bank: str  # "object" or "structure"
    row: int
    bound: InstanceBound
    frame_origin: int = 0
    """Agent whose frame this instance uses (frames agree across a team: ``InstanceFrame``)."""
    frame_version: int = 0
    """Bumped each time that frame is enlarged."""
    alive: bool = True
    """False once merged into another instance (its row stays, unused)."""


@dataclass(frozen=True)
class InstanceFrame:
    """An instance's fixed frame, as agents agree on it: centre (3,), half-size, and its provenance.

    Of two frames of one object the team keeps the one of the lower ``origin`` agent, then the higher
    ``version`` (``better_than``): a total order, so every agent converges to the same frame after one
    exchange each way, and a frame never flips back and forth as confidences change.
    """

    centre: tuple[float, float, float]
    half: float
    origin: int
    version: int

    def better_than(self, other: "InstanceFrame") -> bool:
        return (self.origin, -self.version, self.centre, -self.half) < (other.origin, -other.version, other.centre,
                                                                      -other.half)

    def same_as(self, other: "InstanceFrame", tol: float = 1e-5) -> bool:
        return (abs(self.half - other.half) <= tol * max(1.0, self.half)
                and all(abs(a - b) <= tol * max(1.0, abs(a)) for a, b in zip(self.centre, other.centre)))


@dataclass
class ExportedInstance:
    """Everything a peer needs to hold or adopt one instance's network (see ``mapping.team.messages``)."""

    instance_id: int
    bank: str
    params: np.ndarray  # (D,) float32
    bound_lo: np.ndarray  # (3,)
    bound_hi: np.ndarray  # (3,)
    frame: InstanceFrame
    observed: ObservedSpace | None = None
    """Where the instance's keyframes have looked (None: not kept)."""
