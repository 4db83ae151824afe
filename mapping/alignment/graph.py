"""The Instance Collaborative Graph (paper, sec. III-C).

Vertices are instances of all agents; an edge joins two instances of DIFFERENT agents that exchanged
point clouds when their clouds overlap enough (eq. 3-4): IoU >= ``iou_threshold`` or IoB, in either
direction, >= ``iob_threshold``. The IoB edge is what joins a partial view (viewpoint loss) or a piece
(over-segmentation) to the whole object. Connected components are the clusters, each led by its most
confident member (the reference).

One addition to the paper, for partial views that share only a strip: agents that map different parts
of a room see different parts of the same wall, floor or large object, so both IoU and IoB stay small
(0.05-0.3 in the simulator) although the clouds continue each other. Such a pair is joined when it
shares at least ``partial_min_points`` overlapping points, IoB in either direction reaches
``partial_iob_threshold`` AND the caption features agree (cosine >= ``partial_similarity``). Touching
but different objects overlap along a contact line only (IoB of a few %), and two different objects
of one kind rarely share a strip; a semantic error blocks only this weaker edge, never the paper's.

A vertex is a ``Node`` = (agent, local_id, part): part 0 is a whole local instance; parts 1, 2, ...
are the pieces an under-segmented instance was split into (by the batch alignment,
``studies.batch_alignment.corrections``), so the graph can replace a vertex by its pieces and
cluster again.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from typing import Iterable

import networkx as nx
import numpy as np

from mapping.alignment.overlap import iou_from_counts, pairwise_overlap_counts
from mapping.pointcloud import check_points

Node = tuple[str, int, int]
"""(agent name, local instance id, part): part 0 = the whole instance, >= 1 = a piece of a split one."""


@dataclass(frozen=True)
class Cluster:
    """One connected component of the graph: instances that are one physical object.

    Attributes:
        members: its vertices, sorted.
        reference: the member with the highest confidence (ties: the smallest node), whose caption,
            features and id every member takes.
    """

    members: tuple[Node, ...]
    reference: Node


class InstanceCollaborativeGraph:
    """Cross-agent overlap graph of instance clouds; clusters = connected components.

    Args:
        radius_m: overlap distance of eq. 3-4.
        iou_threshold: edge when IoU >= this.
        iob_threshold: edge when IoB in either direction >= this.
        links: agent pairs that exchanged clouds; None = every pair of agents is linked.
        partial_iob_threshold: IoB of the semantic partial-view edge (module docstring); 1 disables it.
        partial_similarity: caption cosine the partial-view edge needs.
        partial_min_points: overlapping points the partial-view edge needs.
        flat_size_ratio, flat_similarity: an IoB edge is refused between a cloud and one at least
            ``flat_size_ratio`` times larger when their captions' cosine is below ``flat_similarity``
            (a picture lying on a wall is within the overlap radius of it everywhere).
    """

    def __init__(self, radius_m: float, iou_threshold: float, iob_threshold: float,
                 links: Iterable[tuple[str, str]] | None = None, partial_iob_threshold: float = 1.0,
                 partial_similarity: float = 0.6, partial_min_points: int = 30, flat_size_ratio: float = 10.0,
                 flat_similarity: float = 0.3):
        for name, value in (("iou_threshold", iou_threshold), ("iob_threshold", iob_threshold)):
            if not 0.0 < value <= 1.0:
                raise ValueError(f"{name} must be in (0, 1], got {value}")
        if radius_m < 0:
            raise ValueError(f"radius_m must be >= 0, got {radius_m}")
        self.radius_m = radius_m
        self.iou_threshold = iou_threshold
        self.iob_threshold = iob_threshold
        self.links = None if links is None else {frozenset(link) for link in links}
        self.partial_iob_threshold = partial_iob_threshold
        self.partial_similarity = partial_similarity
        self.partial_min_points = partial_min_points
        self.flat_size_ratio = flat_size_ratio
        self.flat_similarity = flat_similarity
        self._feature: dict[Node, np.ndarray] = {}
        self.graph = nx.Graph()
        self._clouds: dict[Node, np.ndarray] = {}
        self._confidence: dict[Node, float] = {}
        self._count: dict[tuple[Node, Node], int] = {}  # (u, v) -> points of u that overlap v, nonzero
        self._overlapping: dict[Node, set[Node]] = defaultdict(set)

    # ----------------------------------------------------------------------------------- building
    def linked(self, agent_a: str, agent_b: str) -> bool:
        """Whether the two (different) agents exchanged clouds."""
        if agent_a == agent_b:
            return False
        return self.links is None or frozenset((agent_a, agent_b)) in self.links

    def add_instances(self, clouds: dict[Node, np.ndarray], confidence: dict[Node, float],
                      features: dict[Node, np.ndarray] | None = None) -> None:
        """Add vertices, measure their overlap with every linked vertex, and add the edges they earn.

        Args:
            clouds: node -> (n, 3) float64 down-sampled world points.
            confidence: node -> eq. 1-2 confidence, for every node in ``clouds``.
            features: node -> (d,) unit caption feature; nodes without one never get the partial edge.
        """
        for node, feature in (features or {}).items():
            self._feature[node] = np.asarray(feature, np.float64).reshape(-1)
        for node, cloud in clouds.items():
            if node in self._clouds:
                raise ValueError(f"node {node} is already in the graph")
            if node not in confidence:
                raise ValueError(f"node {node} has no confidence")
            self._clouds[node] = check_points(cloud, f"points of {node}")
            self._confidence[node] = float(confidence[node])
            self.graph.add_node(node)
        new_by_agent: dict[str, list[Node]] = defaultdict(list)
        for node in sorted(clouds):
            new_by_agent[node[0]].append(node)
        new = set(clouds)
        for agent_a, nodes_a in new_by_agent.items():
            for agent_b in sorted({n[0] for n in self._clouds}):
                if not self.linked(agent_a, agent_b):
                    continue
                # a new node meets an old node once; two new nodes once, from the smaller agent name
                targets = [n for n in sorted(self._clouds) if n[0] == agent_b
                           and (n not in new or agent_a < agent_b)]
                self._measure(nodes_a, targets)

    def pin(self, node: Node, to: Node) -> None:
        """Keep only the edge node - to: a piece cut out of an under-segmented instance belongs to the
        reference it was cut for, even when it also lies flat on another object (a sliver of a window
        frame is within the overlap radius of the wall behind it, too)."""
        self.graph.remove_edges_from(list(self.graph.edges(node)))
        self.graph.add_edge(node, to, iou=self.iou(node, to), kind="split")

    def remove(self, node: Node) -> None:
        """Drop a vertex with its overlaps and edges (before adding its pieces)."""
        for other in self._overlapping.pop(node, set()):
            self._overlapping[other].discard(node)
            self._count.pop((node, other), None)
            self._count.pop((other, node), None)
        self.graph.remove_node(node)
        del self._clouds[node], self._confidence[node]
        self._feature.pop(node, None)

    def _measure(self, nodes_a: list[Node], nodes_b: list[Node]) -> None:
        if not nodes_a or not nodes_b:
            return
        n_ab, n_ba = pairwise_overlap_counts([self._clouds[n] for n in nodes_a],
                                             [self._clouds[n] for n in nodes_b], self.radius_m)
        for i, j in zip(*np.nonzero((n_ab > 0) | (n_ba > 0))):
            u, v = nodes_a[i], nodes_b[j]
            self._count[(u, v)], self._count[(v, u)] = int(n_ab[i, j]), int(n_ba[i, j])
            self._overlapping[u].add(v)
            self._overlapping[v].add(u)
            iob = max(self.iob(u, v), self.iob(v, u))
            if self.iou(u, v) >= self.iou_threshold or (iob >= self.iob_threshold and not self._lies_on(u, v)):
                self.graph.add_edge(u, v, iou=self.iou(u, v), kind="overlap")
            elif iob >= self.partial_iob_threshold and min(n_ab[i, j], n_ba[i, j]) >= self.partial_min_points \
                    and self.similarity(u, v) >= self.partial_similarity:
                self.graph.add_edge(u, v, iou=self.iou(u, v), kind="partial")

    def _lies_on(self, u: Node, v: Node) -> bool:
        """Whether the smaller of u, v is a different, flat thing lying on the larger one (a picture
        on a wall, a rug on the floor): many times smaller, inside it by IoB, and meaning something
        else (caption cosine below ``flat_similarity``). Such a pair gets no IoB edge."""
        small, large = sorted((u, v), key=lambda n: len(self._clouds[n]))
        if len(self._clouds[large]) < self.flat_size_ratio * max(len(self._clouds[small]), 1):
            return False
        return -1.0 < self.similarity(u, v) < self.flat_similarity

    # ------------------------------------------------------------------------------------ queries
    @property
    def nodes(self) -> list[Node]:
        """All vertices, sorted."""
        return sorted(self._clouds)

    def cloud(self, node: Node) -> np.ndarray:
        """(n, 3) float64 down-sampled points of a vertex."""
        return self._clouds[node]

    def confidence(self, node: Node) -> float:
        """Eq. 1-2 confidence of a vertex."""
        return self._confidence[node]

    def overlapping(self, node: Node) -> list[Node]:
        """Vertices of linked agents that share at least one overlapping point with ``node``, sorted."""
        return sorted(self._overlapping.get(node, ()))

    def feature(self, node: Node) -> np.ndarray | None:
        """(d,) caption feature of a vertex, or None."""
        return self._feature.get(node)

    def similarity(self, u: Node, v: Node) -> float:
        """Cosine of the two vertices' caption features (-1 when either has none)."""
        a, b = self._feature.get(u), self._feature.get(v)
        if a is None or b is None or a.shape != b.shape:
            return -1.0
        return float(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12))

    def iob(self, u: Node, v: Node) -> float:
        """Eq. 4, IoB of u into v: share of u's points that overlap v (0 when not measured)."""
        n_u = len(self._clouds[u])
        return self._count.get((u, v), 0) / n_u if n_u else 0.0

    def iou(self, u: Node, v: Node) -> float:
        """Eq. 3 (symmetric); 0 for vertices that do not overlap."""
        if (u, v) not in self._count:
            return 0.0
        return float(iou_from_counts(len(self._clouds[u]), len(self._clouds[v]),
                                     self._count[(u, v)], self._count[(v, u)]))

    def clusters(self) -> list[Cluster]:
        """Connected components with their references, sorted by reference node."""
        out = []
        for component in nx.connected_components(self.graph):
            members = tuple(sorted(component))
            reference = min(members, key=lambda n: (-self._confidence[n], n))
            out.append(Cluster(members, reference))
        return sorted(out, key=lambda c: c.reference)
