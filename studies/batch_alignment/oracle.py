"""Ground-truth alignment (the experiments' upper bound) and the id-consistency diagnostic.

Both read ``source_ids`` (the simulator's ground truth carried on instances and segments), which the
method never does. ``source_ids[0]`` is the dominant ground-truth object of an instance or a mask.
Beside the alignment study, which scores ``align_agents`` against them; team runs have no oracle.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Sequence

import numpy as np

from studies.batch_alignment.align import AgentAlignment, AlignmentResult
from studies.batch_alignment.corrections import corrected_instance
from mapping.data.frame import Frame
from mapping.perception.codebook import CodeBook, CodeBookEntry
from mapping.perception.types import AgentInstance, FrameSegmentation, FusionResult


def oracle_alignment(fused: dict[str, FusionResult], frames: dict[str, Sequence[Frame]] | None = None,
                     segmentations: dict[str, Sequence[FrameSegmentation]] | None = None) -> AlignmentResult:
    """Perfect alignment from ground truth: global id = ground-truth id of the dominant source.

    Ids are the ground-truth ids themselves (not dense). An instance maps to its dominant source
    (over-segmented pieces share it). Label images: each mask takes its segment's dominant source;
    a mask over several objects (``len(source_ids) >= 2``) is split per pixel by the frame's
    ground-truth instance image when the frame has one. An id's meaning comes from the team's most
    confident instance with that dominant source (or, for an object no instance is dominated by, the
    most confident instance that lists it).

    Raises:
        ValueError: an instance carries no ``source_ids``.
    """
    if not fused:
        raise ValueError("oracle_alignment needs the fusion result of at least one agent")
    for a, result in fused.items():
        for lid, inst in result.instances.items():
            if not inst.source_ids:
                raise ValueError(f"oracle alignment: instance {lid} of {a} has no source_ids (ground truth)")
    team_book = CodeBook()
    ranked = sorted(((a, lid, inst) for a in sorted(fused) for lid, inst in fused[a].instances.items()),
                    key=lambda t: (-t[2].confidence, t[0], t[1]))
    for dominant_only in (True, False):
        for _, _, inst in ranked:
            for gt in inst.source_ids[:1] if dominant_only else inst.source_ids:
                team_book.setdefault(int(gt), CodeBookEntry(inst.caption, inst.caption_feature,
                                                            inst.visual_feature, float(inst.confidence)))
    agents = {}
    for a in sorted(fused):
        local_to_global = {lid: int(inst.source_ids[0]) for lid, inst in sorted(fused[a].instances.items())}
        members: dict[int, list[tuple[AgentInstance, np.ndarray]]] = defaultdict(list)
        for lid, inst in sorted(fused[a].instances.items()):
            members[local_to_global[lid]].append((inst, inst.points))
        corrected = {g: corrected_instance(g, _as_instance(team_book[g], m[0][0]), team_book[g].confidence, m)
                     for g, m in sorted(members.items())}
        ids = {int(s) for inst in fused[a].instances.values() for s in inst.source_ids}
        segs = None if segmentations is None else segmentations.get(a)
        labeller = None if segs is None else _OracleLabeller(
            a, fused[a], segs, None if frames is None else frames.get(a))
        agents[a] = AgentAlignment(a, local_to_global, {}, CodeBook({g: team_book[g] for g in sorted(ids)}),
                                   corrected, 0, labeller, [] if segs is None else sorted(s.frame_index for s in segs))
    return AlignmentResult(agents, team_book)


def id_consistency(result: AlignmentResult, fused: dict[str, FusionResult]) -> float:
    """Share of ground-truth objects seen by >= 2 agents that carry ONE global id in all of them.

    An agent sees object g when one of its instances has ``source_ids[0] == g``; the ids it gives g are
    the global ids of all such instances (so an unmerged over-segmentation counts as inconsistent).
    Split (under-segmented) instances have no single dominant object and are skipped. Returns 1.0 when
    no object is seen by two agents (nothing to be inconsistent about).
    """
    ids: dict[int, dict[str, set[int]]] = defaultdict(lambda: defaultdict(set))
    for agent, global_id, source in _dominant_sources(result, fused):
        ids[source][agent].add(global_id)
    shared = [per_agent for per_agent in ids.values() if len(per_agent) >= 2]
    if not shared:
        return 1.0
    consistent = sum(len(set().union(*per_agent.values())) == 1 for per_agent in shared)
    return consistent / len(shared)


def id_purity(result: AlignmentResult, fused: dict[str, FusionResult]) -> float:
    """Share of global ids whose instances (over all agents) are dominated by ONE ground-truth object.

    The counterpart of ``id_consistency``, which one all-swallowing cluster would satisfy: purity
    falls when alignment glues different objects together. Split instances are skipped (as there);
    1.0 when no id has an instance.
    """
    sources: dict[int, set[int]] = defaultdict(set)
    for _, global_id, source in _dominant_sources(result, fused):
        sources[global_id].add(source)
    if not sources:
        return 1.0
    return sum(len(s) == 1 for s in sources.values()) / len(sources)


def _dominant_sources(result: AlignmentResult, fused: dict[str, FusionResult]):
    """(agent, global id, dominant ground-truth id) of every unsplit instance that has a source."""
    for a, fusion in fused.items():
        if a not in result.agents:
            raise ValueError(f"agent {a} is not in the alignment result")
        mapping = result.agents[a].local_to_global
        for lid, inst in fusion.instances.items():
            if inst.source_ids and lid in mapping:
                yield a, mapping[lid], int(inst.source_ids[0])


class _OracleLabeller:
    """Label images in ground-truth ids: dominant source per mask, per pixel for multi-object masks."""

    def __init__(self, agent: str, fusion: FusionResult, segmentations: Sequence[FrameSegmentation],
                 frames: Sequence[Frame] | None):
        self.agent = agent
        self._fusion = fusion
        self._segs = {s.frame_index: s for s in segmentations}
        self._frames = None if frames is None else {f.index: f for f in frames}

    def __call__(self, frame_index: int) -> np.ndarray:
        if frame_index not in self._segs:
            raise ValueError(f"{self.agent}: no segmentation for frame {frame_index}")
        seg = self._segs[frame_index]
        kept = self._fusion.label_image(seg) > 0
        frame = None if self._frames is None else self._frames.get(frame_index)
        out = np.zeros(seg.labels.shape, np.int32)
        for s in seg.segments:
            mask = (seg.labels == s.segment_id) & kept
            if not mask.any():
                continue
            local = self._fusion.assignment[(frame_index, s.segment_id)]
            sources = s.source_ids or self._fusion.instances[local].source_ids
            out[mask] = sources[0]
            if len(sources) >= 2 and frame is not None and frame.instance is not None:
                truth = frame.instance[mask]
                out[mask] = np.where(np.isin(truth, sources), truth, sources[0])
        return out


def _as_instance(entry: CodeBookEntry, like: AgentInstance) -> AgentInstance:
    """An AgentInstance carrying ``entry``'s meaning (the geometry fields are replaced by the caller)."""
    return AgentInstance(like.local_id, entry.caption, entry.caption_feature, entry.visual_feature,
                         entry.confidence, like.points, like.colour)
