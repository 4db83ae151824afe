"""Cross-Agent Instance Alignment on arrival (paper sec. III-C, run as messages come in).

A peer's instances arrive with their down-sampled clouds; each is tested against the receiver's own
instances with the Instance Collaborative Graph's edge rules (IoU / IoB of eq. 3-4, the semantic
partial-view edge, no IoB edge for a flat thing lying on a much larger, different surface) and
becomes one of:

- ``match``: it is one of my instances (the one with the highest IoU among its neighbours);
- ``adopt``: I have never seen it: I take it whole (network, box, frame, code-book entry);
- ``merge`` + ``match``: two or more of my instances lie inside it (IoB of each into it >= the split
  threshold) AND mean the same (caption cosine >= ``merge_similarity`` with the largest of them):
  they are over-segmented pieces of one object and become one (the oldest id); the paper merges
  "overlapping masks with similar features", and the feature test is what keeps a mug standing against
  a book two objects when a peer's coarse mask covers both.

The reference of eq. 1-2 (the more confident side) decides the meaning: a matched instance whose peer
is more confident takes the peer's caption and feature (``take_meaning``). Under-segmentation on my
side is left to the peer: when it receives my two pieces it matches both to its coarse instance; the
online path does not split masks (the batch ``align_agents`` beside the alignment benchmark,
``studies.batch_alignment``, does).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mapping.alignment.config import AlignmentConfig
from mapping.alignment.graph import InstanceCollaborativeGraph
from mapping.config_fields import bounded


@dataclass(frozen=True)
class ArrivalConfig:
    """Thresholds of the alignment on arrival."""

    alignment: AlignmentConfig = field(default_factory=AlignmentConfig)
    """The graph's edge rules (same values as the batch alignment)."""
    merge_similarity: float = field(default=0.6, metadata=bounded(-1, 1))
    """Caption cosine two of my instances need to be merged as pieces of one object."""


@dataclass
class ArrivalDecision:
    """What to do with one arrived instance: ``kind`` is ``match`` or ``adopt``; ``own_id`` the matched
    instance; ``merged`` my instances folded into ``own_id`` first; ``take_meaning`` whether the peer is
    the reference (more confident)."""

    peer_id: int
    kind: str
    own_id: int | None = None
    merged: tuple[int, ...] = ()
    take_meaning: bool = False


@dataclass
class InstanceView:
    """What alignment reads of one instance: (P, 3) cloud, (d,) unit caption feature, confidence."""

    cloud: np.ndarray
    feature: np.ndarray
    confidence: float


def align_arrivals(own: dict[int, InstanceView], arrived: dict[int, InstanceView],
                   config: ArrivalConfig = ArrivalConfig()) -> list[ArrivalDecision]:
    """Decide, for each arrived instance (peer id -> view), match, adopt or merge-and-match."""
    if not arrived:
        return []
    a = config.alignment
    graph = InstanceCollaborativeGraph(a.overlap_radius_m, a.iou_threshold, a.iob_threshold,
                                       partial_iob_threshold=a.partial_iob_threshold,
                                       partial_similarity=a.partial_similarity,
                                       partial_min_points=a.partial_min_points, flat_size_ratio=a.flat_size_ratio,
                                       flat_similarity=a.flat_similarity)
    mine = {("me", i, 0): v for i, v in own.items() if len(v.cloud)}
    theirs = {("peer", i, 0): v for i, v in arrived.items() if len(v.cloud)}
    views = {**mine, **theirs}
    graph.add_instances({n: v.cloud for n, v in views.items()}, {n: v.confidence for n, v in views.items()},
                        {n: v.feature for n, v in views.items()})
    decisions, merged_away = [], set()
    for node in sorted(theirs):
        peer_id = node[1]
        neighbours = [m for m in graph.graph.neighbors(node) if m[0] == "me" and m[1] not in merged_away]
        if not neighbours:
            decisions.append(ArrivalDecision(peer_id, "adopt"))
            continue
        pieces = sorted((m for m in neighbours if graph.iob(m, node) >= a.split_iob_threshold),
                        key=lambda m: (-len(mine[m].cloud), m))
        merged: tuple[int, ...] = ()
        if len(pieces) >= 2:
            lead = pieces[0]
            same = [m for m in pieces[1:] if graph.similarity(m, lead) >= config.merge_similarity]
            if same:
                keep = min([lead] + same, key=lambda m: m[1])  # the oldest id survives
                merged = tuple(sorted(m[1] for m in [lead] + same if m != keep))
                merged_away.update(merged)
                neighbours = [m for m in neighbours if m[1] not in merged]
                target = keep
            else:
                target = max(neighbours, key=lambda m: (graph.iou(node, m), -m[1]))
        else:
            target = max(neighbours, key=lambda m: (graph.iou(node, m), -m[1]))
        take = arrived[peer_id].confidence > own[target[1]].confidence
        decisions.append(ArrivalDecision(peer_id, "match", target[1], merged, take))
    return decisions
