"""What a round did and what each agent knows after it: typed records returned by ``Team.round``.

``RoundReport`` is the round's account (bytes per link, deliveries, alignment counts, loss terms,
seconds); ``AgentSnapshot`` is one agent's own knowledge after the round (its frames, its position, what
it holds of each peer, its budget and messages), the only thing the env builds observations from.
``RoundReport.as_dict`` is the JSON form written to ``rounds.json`` (snapshots are not in it).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from mapping.data.frame import Frame
from mapping.team.links import LinkLimits

DELIVERY_STATUSES = ("delivered", "dropped", "over_budget")


@dataclass(frozen=True)
class DeliveryRecord:
    """One message on one link this round: ``status`` is delivered, dropped (link failure) or
    over_budget (refused: its sender's budget was spent)."""

    sender: int
    receiver: int
    kind: str
    """``params``, ``rays`` or ``points``."""
    status: str
    bytes: int


@dataclass
class AlignmentCounts:
    """What a receiver did with the instances that arrived (sec. III-C)."""

    adopted: int = 0
    """Instances it had never seen, taken whole."""
    matched: int = 0
    """Instances matched to one of its own over the Instance Collaborative Graph."""
    merged: int = 0
    """Own pieces merged into a matched instance (over-segmentation fixed)."""
    refit: int = 0
    """Own instances moved to the frame agreed with the peer."""

    def add(self, other: "AlignmentCounts") -> None:
        self.adopted += other.adopted
        self.matched += other.matched
        self.merged += other.merged
        self.refit += other.refit


@dataclass
class ConsistencyTerms:
    """The consistency iterations of one agent in one round (eq. 12 + 13), last iteration's values."""

    parameter: float = 0.0
    """Parameter consistency (eq. 12)."""
    render: float = 0.0
    """Render consistency (eq. 13), before its weight."""
    render_rays: int = 0
    """Shared rays eq. 13 used."""
    pairs: int = 0
    """(own instance, peer vector) pairs under eq. 12."""
    loss: float | None = None
    """The whole objective of the last consistency iteration (None: no iteration ran)."""
    seconds: float = 0.0


@dataclass
class LossTerms:
    """One agent's losses in one round: its local phase and its consistency phase."""

    data: float
    """The data loss (eq. 8-11) of the last local iteration."""
    local_parameter: float
    """Eq. 12's consensus term inside the local iterations (0 without ``local_consensus``)."""
    consistency: ConsistencyTerms

    def as_dict(self) -> dict:
        terms = asdict(self.consistency)
        terms.pop("seconds")
        if terms["loss"] is None:
            terms.pop("loss")
        return {"data": self.data, "local_parameter": self.local_parameter, **terms}


@dataclass(frozen=True)
class PeerKnowledge:
    """What an agent knows of one peer: from the parameter and ray messages it received from it."""

    held_instances: int
    """Instances of the peer it holds (their last parameters)."""
    held_object_boxes: tuple[tuple[np.ndarray, np.ndarray], ...]
    """(lo, hi) boxes of the held object instances (walls, floor, ceiling left out)."""
    last_parameters_round: int | None
    """Round of the last parameter message that arrived from the peer (None: none yet)."""
    position: tuple[int, np.ndarray] | None
    """(round, (3,) position) of the peer from its last ray message (None: none yet)."""


@dataclass(frozen=True)
class LinkState:
    """What an agent knows of its own side of the link to one peer, from the link's acknowledgements:
    what the peer holds of its map and when it last reached it."""

    holds: float
    """Share of its shareable instances the peer holds in some version (0 with none)."""
    up_to_date: float
    """Share the peer holds within ``ExchangeConfig.up_to_date_tolerance`` of their parameters now."""
    change: float
    """Mean relative change (L2) of its shareable instances since the version the peer holds, each at most
    1 (1 for an instance the peer lacks; 0 with no shareable instance)."""
    params_round: int | None
    """Round of its last parameter message that reached the peer (None: none yet)."""
    rays_round: int | None
    """Round of its last ray message that reached the peer (None: none yet)."""
    bytes_sent: int
    """Bytes it has sent to the peer over the episode (delivered or not)."""


@dataclass(frozen=True)
class InstanceOnLink:
    """What an agent knows of one of its own shareable instances on its link to one peer (what the link
    acknowledged, what alignment matched): the unit an instance-level message chooses."""

    instance_id: int
    lacks: bool
    """The peer holds no copy of it."""
    change: float
    """Relative L2 change since the peer's copy, at most 1 (1 when it lacks it)."""
    copy_round: int | None
    """Round the peer's copy reached it (None: never)."""
    shared: bool
    """The peer maps it too: one of the peer's own instances matched it over the Instance Collaborative Graph."""
    confidence: float
    """Its confidence (eq. 1-2)."""
    diagonal_m: float
    """Its box's diagonal."""
    born_round: int
    """Round it first appeared in the agent's map."""
    nbytes: int
    """Bytes of its network vector on the wire."""


def priority_order(items: list[InstanceOnLink]) -> list[InstanceOnLink]:
    """The documented order of an agent's instances on a link (``instances`` observation slots): those the peer
    lacks first, then by change since the peer's copy (largest first), then those it maps too, then by id."""
    return sorted(items, key=lambda x: (not x.lacks, -round(x.change, 6), not x.shared, x.instance_id))


@dataclass
class AgentSnapshot:
    """One agent's own knowledge after a round (never ground truth)."""

    index: int
    rounds: int
    """Rounds the team has done."""
    frames_read: int
    """Frames of its stream it has read so far."""
    new_frames: tuple[Frame, ...]
    """The frames it read in the last round (RGB-D, its own pose)."""
    position: np.ndarray | None
    """(3,) its camera position at its last frame (None before the first)."""
    instances: int
    """Live instances of its map."""
    instances_own: int
    """Of those, instances with pixels of its own frames (the rest came from peers)."""
    peers: dict[int, PeerKnowledge]
    """What it holds of each peer that has sent it something."""
    budget_left_bytes: float
    """Bytes it may still send (inf without a budget)."""
    bytes_sent_total: int
    bytes_sent: int = 0
    """This round."""
    bytes_received: int = 0
    """This round."""
    messages: dict[str, int] = field(default_factory=lambda: dict.fromkeys(DELIVERY_STATUSES, 0))
    """Its own messages of this round by status (delivered, dropped, over_budget)."""
    links: dict[int, LinkState] = field(default_factory=dict)
    """Its side of the link to every peer."""
    frames_total: int = 0
    """Frames on its path (it knows the path it was given)."""
    instance_links: dict[int, tuple[InstanceOnLink, ...]] = field(default_factory=dict)
    """Per peer, its shareable instances on that link in ``priority_order``."""
    map_bytes: int = 0
    """Bytes of all its shareable instances' network vectors on the wire (what a full message costs, roughly)."""
    links_up: dict[int, bool] = field(default_factory=dict)
    """Per peer, whether the link was up in the last round (its radio's view; every link before the first)."""

    @property
    def name(self) -> str:
        return f"agent_{self.index}"


@dataclass
class RoundReport:
    """What one round did. Per-agent lists are indexed by agent; losses and alignment by agent name."""

    round: int
    frames_read: list[int]
    keyframes: list[int]
    bytes_per_link: np.ndarray
    """(N, N) bytes sent i -> j this round."""
    bytes_sent: list[int]
    bytes_received: list[int]
    delivered: int
    dropped: int
    over_budget: int
    deliveries: list[DeliveryRecord]
    alignment: dict[str, AlignmentCounts]
    losses: dict[str, LossTerms]
    local_s: list[float]
    consistency_s: list[float]
    exchange_s: float
    done: bool
    agents: list[AgentSnapshot] = field(default_factory=list)
    """Each agent's knowledge after the round."""
    links: LinkLimits | None = None
    """Which links were up and the room each had at the round's start (``mapping.team.links``)."""

    @property
    def compute_s(self) -> list[float]:
        """Each agent's own compute seconds this round."""
        return [a + b for a, b in zip(self.local_s, self.consistency_s)]

    @property
    def fleet_s(self) -> float:
        """Wall clock of a fleet with one computer per robot: slowest local phase + exchange + slowest
        consistency phase."""
        return max(self.local_s, default=0.0) + self.exchange_s + max(self.consistency_s, default=0.0)

    def as_dict(self) -> dict:
        """The JSON form (``rounds.json``, checkpoints): plain types, no snapshots, no deliveries."""
        return {"round": self.round, "frames_read": list(self.frames_read), "keyframes": list(self.keyframes),
                "bytes_per_link": self.bytes_per_link.tolist(), "bytes_sent": list(self.bytes_sent),
                "bytes_received": list(self.bytes_received), "delivered": self.delivered, "dropped": self.dropped,
                "over_budget": self.over_budget,
                "alignment": {name: asdict(counts) for name, counts in self.alignment.items()},
                "losses": {name: terms.as_dict() for name, terms in self.losses.items()},
                "local_s": list(self.local_s), "consistency_s": list(self.consistency_s),
                "exchange_s": self.exchange_s, "done": self.done, "compute_s": self.compute_s, "fleet_s": self.fleet_s,
                **({"links": self.links.as_dict()} if self.links is not None else {})}


__all__ = ["AgentSnapshot", "AlignmentCounts", "ConsistencyTerms", "DELIVERY_STATUSES", "DeliveryRecord",
           "InstanceOnLink", "LossTerms", "PeerKnowledge", "RoundReport", "priority_order"]
