"""Batch cross-agent instance alignment (paper, sec. III-C): the entry point and its result.

``align_agents`` runs the whole module on the agents' fused instances:
exchange (down-sampled clouds, bytes counted) -> Instance Collaborative Graph -> split the
under-segmented instances (repeat until none is left) -> clusters -> global ids -> corrections.

Global ids are dense from 1, the same for all agents: clusters sorted by their reference's
(agent, local id, part). The result is injective: each agent's corrected instances are keyed by global
id (over-segmented pieces merged into one), and a global id names one cluster, i.e. one physical
object, in every agent. ``no_alignment`` is the ablation without cross-agent alignment.

Batch: every agent's fused instances of all its frames are aligned at once. Only the alignment
study (``studies.alignment``) and its tests run it, so it sits beside that study;
the team aligns online, as each peer's instances arrive (``mapping.team.arrival``), with the same
options (``mapping.alignment.config``) and the same Instance Collaborative Graph
(``mapping.alignment.graph``).
"""

from __future__ import annotations

import itertools
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from studies.batch_alignment.corrections import (LabelFunction, MaskRelabeller, corrected_instance,
                                                    find_under_segmented, nearest_piece, split_points)
from studies.batch_alignment.messages import message_bytes
from mapping.alignment.config import AlignmentConfig
from mapping.alignment.graph import Cluster, InstanceCollaborativeGraph, Node
from mapping.data.frame import Frame
from mapping.perception.codebook import CodeBook, CodeBookEntry
from mapping.perception.types import AgentInstance, FrameSegmentation, FusionResult
from mapping.pointcloud import voxel_downsample


@dataclass
class AgentAlignment:
    """One agent's view of the aligned team.

    Attributes:
        agent: the agent's name.
        local_to_global: local id -> global id for every instance that maps to ONE global id
            (over-segmented pieces share one).
        split: local id -> global ids of each under-segmented instance, whose masks are split per
            pixel in ``corrected_labels``.
        codebook: global id -> the reference's caption, features and confidence, for this agent's ids.
        instances: global id -> corrected instance (own points, merged; the reference's meaning).
        bytes_sent: bytes of this agent's alignment messages over all its links.
    """

    agent: str
    local_to_global: dict[int, int]
    split: dict[int, tuple[int, ...]]
    codebook: CodeBook
    instances: dict[int, AgentInstance]
    bytes_sent: int = 0
    labeller: LabelFunction | None = field(default=None, repr=False)
    frame_indices: list[int] = field(default_factory=list)

    def corrected_labels(self, frame_index: int) -> np.ndarray:
        """(H, W) int32 global ids of one frame's corrected masks (0 = no mask)."""
        if self.labeller is None:
            raise ValueError(f"{self.agent}: no segmentations were given, so there are no label images")
        return self.labeller(frame_index)

    def global_ids_of(self, local_id: int) -> tuple[int, ...]:
        """All global ids a local instance maps to (several when it was split)."""
        if local_id in self.local_to_global:
            return (self.local_to_global[local_id],)
        if local_id in self.split:
            return self.split[local_id]
        raise KeyError(f"{self.agent} has no local instance {local_id}")


@dataclass
class AlignmentResult:
    """The aligned team.

    Attributes:
        agents: agent name -> its alignment.
        codebook: every global id -> its reference's meaning.
        clusters: global id -> its cluster in the graph (empty for ``no_alignment`` and the oracle).
        bytes_per_link: (agent_a, agent_b), a < b -> bytes both ways over that link.
    """

    agents: dict[str, AgentAlignment]
    codebook: CodeBook
    clusters: dict[int, Cluster] = field(default_factory=dict)
    bytes_per_link: dict[tuple[str, str], int] = field(default_factory=dict)

    @property
    def bytes_sent(self) -> dict[str, int]:
        """Agent name -> bytes it sent."""
        return {name: a.bytes_sent for name, a in self.agents.items()}

    def corrected_labels(self, agent: str, frame_index: int) -> np.ndarray:
        """(H, W) int32 global ids of one agent's frame."""
        return self.agents[agent].corrected_labels(frame_index)


def align_agents(fused: dict[str, FusionResult], frames: dict[str, Sequence[Frame]] | None = None,
                 segmentations: dict[str, Sequence[FrameSegmentation]] | None = None,
                 config: AlignmentConfig = AlignmentConfig(),
                 links: Iterable[tuple[str, str]] | None = None) -> AlignmentResult:
    """Align the fused instances of all agents (sec. III-C).

    Args:
        fused: agent name -> its cross-frame fusion result.
        frames: agent name -> its frames; needed to split the masks of under-segmented instances.
        segmentations: agent name -> its frames' masks; needed for ``corrected_labels``.
        config: thresholds and sizes.
        links: agent pairs that exchanged clouds; None = all pairs.

    Returns:
        per agent: local -> global ids, corrected labels, code book, bytes sent.
    """
    links = _check_inputs(fused, frames, segmentations, links)
    names = sorted(fused)
    instances = {(a, lid, 0): inst for a in names for lid, inst in fused[a].instances.items()}
    clouds = {n: voxel_downsample(inst.points, config.voxel_size_m) for n, inst in instances.items()}
    confidence = {n: float(inst.confidence) for n, inst in instances.items()}
    for node, c in confidence.items():
        if not np.isfinite(c):
            raise ValueError(f"instance {node[1]} of {node[0]} has a non-finite confidence {c}")

    # exchange: every agent sends its down-sampled instances once over each of its links
    payload = {a: message_bytes([instances[n] for n in sorted(clouds) if n[0] == a],
                                [clouds[n] for n in sorted(clouds) if n[0] == a]) for a in names}
    bytes_per_link = {(a, b): payload[a] + payload[b] for a, b in links}
    bytes_sent = {a: sum(payload[a] for link in links if a in link) for a in names}

    graph = InstanceCollaborativeGraph(config.overlap_radius_m, config.iou_threshold, config.iob_threshold, links,
                                       config.partial_iob_threshold, config.partial_similarity, config.partial_min_points,
                                       config.flat_size_ratio, config.flat_similarity)
    graph.add_instances(clouds, confidence, {n: inst.caption_feature for n, inst in instances.items()})
    # pieces of split instances -> pixel clouds; and the whole instance whose meaning each piece has
    piece_cloud, meaning_of = _split_under_segmented(graph, config)

    def meaning(node: Node) -> AgentInstance:
        """The fused instance whose caption and features a vertex carries (a piece: its reference's)."""
        return instances[meaning_of.get(node, (node[0], node[1], 0))]

    clusters = graph.clusters()
    global_of = {node: gid for gid, c in enumerate(clusters, start=1) for node in c.members}
    reference = {gid: c.reference for gid, c in enumerate(clusters, start=1)}
    team_book = CodeBook({gid: _entry(meaning(r), graph.confidence(r)) for gid, r in reference.items()})

    agents = {}
    for a in names:
        nodes = [n for n in graph.nodes if n[0] == a]
        by_local: dict[int, set[int]] = defaultdict(set)
        for n in nodes:
            by_local[n[1]].add(global_of[n])
        local_to_global = {lid: next(iter(g)) for lid, g in sorted(by_local.items()) if len(g) == 1}
        split = {lid: tuple(sorted(g)) for lid, g in sorted(by_local.items()) if len(g) > 1}
        members = _members_by_global(a, nodes, fused[a], split, global_of, piece_cloud)
        corrected = {gid: corrected_instance(gid, meaning(reference[gid]), graph.confidence(reference[gid]),
                                             members[gid])
                     for gid in sorted(members)}
        pieces = {lid: [(gid, np.concatenate([piece_cloud[n] for n in nodes if n[1] == lid and global_of[n] == gid]))
                        for gid in gids] for lid, gids in split.items()}
        agents[a] = _agent_alignment(a, fused[a], frames, segmentations, local_to_global, split,
                                     CodeBook({g: team_book[g] for g in corrected}), corrected, pieces)
        agents[a].bytes_sent = bytes_sent[a]
    return AlignmentResult(agents, team_book, dict(enumerate(clusters, start=1)), bytes_per_link)


def no_alignment(fused: dict[str, FusionResult], frames: dict[str, Sequence[Frame]] | None = None,
                 segmentations: dict[str, Sequence[FrameSegmentation]] | None = None) -> AlignmentResult:
    """The ablation without cross-agent alignment: every local instance gets its own global id.

    Agents in name order, local ids ascending: agent_0's instances get 1..n0, agent_1's n0+1.., so no
    two agents share an id; features stay the agent's own. Nothing is sent.
    """
    _check_inputs(fused, frames, segmentations, [])
    agents, team_book, next_id = {}, CodeBook(), 1
    for a in sorted(fused):
        local_to_global = {}
        for lid in sorted(fused[a].instances):
            local_to_global[lid], next_id = next_id, next_id + 1
        corrected = {g: corrected_instance(g, fused[a].instances[lid], fused[a].instances[lid].confidence,
                                           [(fused[a].instances[lid], fused[a].instances[lid].points)])
                     for lid, g in local_to_global.items()}
        book = CodeBook({g: _entry(inst, inst.confidence) for g, inst in corrected.items()})
        team_book.update(book)
        agents[a] = _agent_alignment(a, fused[a], frames, segmentations, local_to_global, {}, book, corrected, {})
    return AlignmentResult(agents, team_book)


# --------------------------------------------------------------------------------------- helpers
def _check_inputs(fused, frames, segmentations, links) -> list[tuple[str, str]]:
    """Validate the inputs; returns the links as sorted (a, b) pairs with a < b."""
    if not fused:
        raise ValueError("align needs the fusion result of at least one agent")
    for what, d in (("frames", frames), ("segmentations", segmentations)):
        if d is not None and set(d) - set(fused):
            raise ValueError(f"{what} given for unknown agents {sorted(set(d) - set(fused))}")
    for a, result in fused.items():
        for lid, inst in result.instances.items():
            if lid != inst.local_id:
                raise ValueError(f"{a}: instance stored under {lid} says local_id {inst.local_id}")
    if links is None:
        return list(itertools.combinations(sorted(fused), 2))
    out = set()
    for link in links:
        a, b = tuple(link)
        if a == b or a not in fused or b not in fused:
            raise ValueError(f"bad link {link!r}: it must join two different known agents {sorted(fused)}")
        out.add((min(a, b), max(a, b)))
    return sorted(out)


def _split_under_segmented(graph: InstanceCollaborativeGraph,
                           config: AlignmentConfig) -> tuple[dict[Node, np.ndarray], dict[Node, Node]]:
    """Replace every under-segmented vertex by its pieces, round after round (item 3).

    A piece matched to a reference takes that reference's meaning and at most its confidence (so a
    piece of a wrongly merged mask never outranks the agent that segmented the object right); a
    remainder piece keeps the split instance's own.

    Returns:
        piece node -> cloud its pixels are matched against (its own points plus its reference's);
        piece node -> the whole-instance vertex (part 0) whose meaning it carries.
    """
    piece_cloud: dict[Node, np.ndarray] = {}
    meaning_of: dict[Node, Node] = {}
    cut_for: dict[Node, Node] = {}  # piece -> the reference vertex it was cut for
    next_part: dict[tuple[str, int], int] = defaultdict(lambda: 1)
    for _ in range(config.max_split_rounds):
        decisions = find_under_segmented(graph, config.split_iob_threshold, config.split_share_threshold,
                                         config.split_min_piece_share, config.split_min_points)
        if not decisions:
            break
        new_clouds, new_conf, new_feat = {}, {}, {}
        for d in decisions:
            points = graph.cloud(d.node)
            refs = [graph.cloud(r) for r in d.references]
            labels = split_points(points, refs, config.split_radius_m, config.min_remainder_fraction)
            for k in np.unique(labels):
                key = (d.node[0], d.node[1])
                part = (key[0], key[1], next_part[key])
                next_part[key] += 1
                own = points[labels == k]
                source = d.references[k] if k < len(refs) else d.node
                meaning_of[part] = meaning_of.get(source, (source[0], source[1], 0))
                if k < len(refs):
                    cut_for[part] = source
                new_clouds[part] = own
                new_conf[part] = min(graph.confidence(d.node), graph.confidence(source))
                feature = graph.feature(d.references[k]) if k < len(refs) else graph.feature(d.node)
                if feature is not None:  # a piece means what its reference means
                    new_feat[part] = feature
                piece_cloud[part] = own if k == len(refs) else np.concatenate([own, refs[k]])
        for d in decisions:
            graph.remove(d.node)
            piece_cloud.pop(d.node, None)
        graph.add_instances(new_clouds, new_conf, new_feat)
    for piece, reference in cut_for.items():
        if piece in graph.graph and reference in graph.graph:
            graph.pin(piece, reference)
    return piece_cloud, meaning_of


def _members_by_global(agent: str, nodes: list[Node], fusion: FusionResult, split: dict[int, tuple[int, ...]],
                       global_of: dict[Node, int], piece_cloud: dict[Node, np.ndarray]):
    """global id -> [(local instance, its points in that cluster)] of one agent."""
    members: dict[int, list] = defaultdict(list)
    for lid, inst in sorted(fusion.instances.items()):
        own = [n for n in nodes if n[1] == lid]
        if lid not in split:
            members[global_of[own[0]]].append((inst, inst.points))
            continue
        gids = split[lid]
        clouds = [np.concatenate([piece_cloud[n] for n in own if global_of[n] == g]) for g in gids]
        which = nearest_piece(inst.points, clouds) if len(inst.points) else np.zeros(0, int)
        for k, g in enumerate(gids):
            members[g].append((inst, inst.points[which == k]))
    return members


def _agent_alignment(agent, fusion, frames, segmentations, local_to_global, split, book, corrected, pieces):
    segs = None if segmentations is None else segmentations.get(agent)
    labeller = None
    if segs is not None:
        labeller = MaskRelabeller(agent, fusion, segs, None if frames is None else frames.get(agent),
                                  local_to_global, pieces)
    return AgentAlignment(agent, local_to_global, split, book, corrected, 0, labeller,
                          [] if labeller is None else labeller.frame_indices)


def _entry(inst: AgentInstance, confidence: float) -> CodeBookEntry:
    return CodeBookEntry(inst.caption, inst.caption_feature, inst.visual_feature, float(confidence))
