"""The paper's corrections over the Instance Collaborative Graph (sec. III-C, items 1-3).

1. Semantic errors and viewpoint loss: every member of a cluster takes the reference's caption,
   features and global id and keeps its own masks (``corrected_instance``).
2. Over-segmentation: several instances of one agent in one cluster become one instance with one
   global id (``corrected_instance`` merges their points and observations).
3. Under-segmentation: one instance of agent k that holds two or more instances of another agent
   j is split (``find_under_segmented``, ``split_points``), and each of its mask pixels goes to the
   nearest piece (``MaskRelabeller``), giving the corrected masks m-bar.

Which side is right when agent j sees several instances where agent k sees one (j over-segmented, or
k under-segmented)? The geometry is the same either way, so, as everywhere in the paper, confidence
decides: the finer view wins when its most confident piece beats the coarse instance and every
instance of a third agent that also holds two of the pieces together. The paper also asks for "similar
semantic features" when merging; that is not used, because its own under-segmentation example (two
cups side by side) has similar captions too.

Split must happen before clustering, or the coarse instance would glue its pieces' clusters together.

Used by the batch ``align_agents`` (``align``) and the oracle (``oracle``), beside the alignment
study: the team's online alignment (``mapping.team.arrival``) merges pieces but never splits masks.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from mapping.alignment.graph import InstanceCollaborativeGraph, Node
from mapping.data.frame import Frame
from mapping.perception.types import AgentInstance, FrameSegmentation, FusionResult


@dataclass(frozen=True)
class SplitDecision:
    """An under-segmented vertex and the pieces of one other agent that it covers.

    Attributes:
        node: the coarse vertex to split.
        references: the other agent's vertices lying inside it (IoB into it >= threshold), sorted.
        confidence: the highest confidence among ``references`` (what beat ``node``).
    """

    node: Node
    references: tuple[Node, ...]
    confidence: float


def find_under_segmented(graph: InstanceCollaborativeGraph, split_iob_threshold: float,
                         split_share_threshold: float, min_piece_share: float = 0.0,
                         min_points: int = 0) -> list[SplitDecision]:
    """Vertices that hold >= 2 vertices of one other agent, and lose the confidence comparison.

    Vertex v (agent j) is a piece of u when it lies mostly inside u (IoB(v -> u) >= split_iob_threshold)
    or holds a real share of u (IoB(u -> v) >= split_share_threshold: u saw the objects only partly).
    With two or more pieces from agent j, u is split when max confidence(pieces) exceeds the confidence
    of u and of every vertex w of a third agent that also holds two or more of the pieces.
    Among several agents, the one with the most confident pieces gives the split.

    A sliver that merely lies ON u (a window frame or a picture flat against a wall: every point of it
    is within the overlap radius of the wall) is not a piece of u: a piece must also hold at least
    ``min_piece_share`` of u's points (IoB(u -> v)) or be seen better than u (higher confidence).
    Clouds of fewer than ``min_points`` points are too small to tell two objects apart: they are
    neither split nor pieces.

    Returns:
        decisions sorted by node; a vertex appears at most once.
    """
    def is_piece(v: Node, u: Node) -> bool:
        if len(graph.cloud(v)) < min_points:
            return False
        if graph.iob(u, v) < min_piece_share and graph.confidence(v) <= graph.confidence(u):
            return False
        return graph.iob(v, u) >= split_iob_threshold or graph.iob(u, v) >= split_share_threshold

    decisions = []
    for u in graph.nodes:
        if len(graph.cloud(u)) < min_points:
            continue
        pieces: dict[str, list[Node]] = defaultdict(list)
        for v in graph.overlapping(u):
            if is_piece(v, u):
                pieces[v[0]].append(v)
        best: SplitDecision | None = None
        for agent_j in sorted(pieces):
            if len(pieces[agent_j]) < 2:
                continue
            whole = [graph.confidence(u)] + [
                graph.confidence(w) for w in graph.overlapping(u)
                if w[0] != agent_j and sum(is_piece(v, w) for v in pieces[agent_j]) >= 2]
            piece_conf = max(graph.confidence(v) for v in pieces[agent_j])
            if piece_conf > max(whole) and (best is None or piece_conf > best.confidence):
                best = SplitDecision(u, tuple(pieces[agent_j]), piece_conf)
        if best is not None:
            decisions.append(best)
    return decisions


def split_points(points: np.ndarray, references: Sequence[np.ndarray], split_radius_m: float,
                 min_remainder_fraction: float) -> np.ndarray:
    """Give each point of an under-segmented cloud to its nearest reference cloud.

    Points farther than ``split_radius_m`` from every reference belong to no reference: a third object
    that the other agent did not see. They form a remainder piece of their own when they are at least
    ``min_remainder_fraction`` of the cloud, else they go to their nearest reference too.

    Args:
        points: (n, 3) float the coarse instance's points.
        references: r clouds (m_i, 3), each non-empty.
        split_radius_m: farthest distance at which a point still belongs to a reference.
        min_remainder_fraction: smallest share of points that makes a remainder piece.

    Returns:
        (n,) int64 piece index per point: 0..r-1 a reference, r the remainder.
    """
    if not references or any(len(r) == 0 for r in references):
        raise ValueError("split_points needs at least one reference, and no empty reference cloud")
    if len(points) == 0:
        return np.zeros(0, np.int64)
    dist = np.stack([cKDTree(r).query(points, k=1)[0] for r in references], axis=1)  # (n, r)
    labels = np.argmin(dist, axis=1)
    far = dist.min(axis=1) > split_radius_m
    if np.count_nonzero(far) >= min_remainder_fraction * len(points):
        labels[far] = len(references)
    return labels


def nearest_piece(points: np.ndarray, pieces: Sequence[np.ndarray]) -> np.ndarray:
    """(n,) index of the piece cloud nearest to each of ``points`` (n, 3)."""
    stacked = np.concatenate(pieces)
    owner = np.repeat(np.arange(len(pieces)), [len(p) for p in pieces])
    return owner[cKDTree(stacked).query(points, k=1)[1]]


def corrected_instance(global_id: int, reference: AgentInstance, reference_confidence: float,
                       members: Sequence[tuple[AgentInstance, np.ndarray]]) -> AgentInstance:
    """One agent's corrected instance: its own geometry, the reference's meaning (items 1 and 2).

    Args:
        global_id: the cluster's id, stored as the instance's ``local_id``.
        reference: the cluster's reference instance (possibly of another agent).
        reference_confidence: the reference vertex's confidence.
        members: this agent's (instance, points) in the cluster: several for over-segmentation;
            for a piece of a split instance, the points are that piece's share.

    Returns:
        points merged, observations united, caption / features / confidence from the reference.
    """
    members = sorted(members, key=lambda m: -len(m[1]))
    points = np.concatenate([p for _, p in members])
    weights = np.array([max(len(p), 1) for _, p in members], np.float64)
    colour = np.average(np.stack([np.asarray(inst.colour, np.float64) for inst, _ in members]), axis=0,
                        weights=weights)
    observations = sorted({obs for inst, _ in members for obs in inst.observations})
    source_ids = tuple(dict.fromkeys(s for inst, _ in members for s in inst.source_ids))
    return replace(reference, local_id=global_id, confidence=reference_confidence, points=points,
                   colour=colour, observations=observations, source_ids=source_ids)


class MaskRelabeller:
    """Corrected label images m-bar of one agent: its masks in global ids, split masks per pixel.

    Args:
        agent: the agent's name (for messages).
        fusion: the agent's fusion result (mask -> local id).
        segmentations: the agent's frames' masks, or None (then no label image can be made).
        frames: the agent's frames, needed only when a split instance appears in a frame.
        local_to_global: local id -> global id of every instance that maps to one global id.
        split_pieces: local id -> [(global id, (m, 3) piece cloud)] of every split instance.
    """

    def __init__(self, agent: str, fusion: FusionResult, segmentations: Sequence[FrameSegmentation] | None,
                 frames: Sequence[Frame] | None, local_to_global: dict[int, int],
                 split_pieces: dict[int, list[tuple[int, np.ndarray]]]):
        self.agent = agent
        self._fusion = fusion
        self._segmentations = None if segmentations is None else {s.frame_index: s for s in segmentations}
        self._frames = frames
        self._frame_by_index: dict[int, Frame] | None = None
        self._split = split_pieces
        size = max([0, *local_to_global, *split_pieces, *fusion.instances]) + 1
        self._lut = np.zeros(size, np.int32)
        for local, glob in local_to_global.items():
            self._lut[local] = glob

    @property
    def frame_indices(self) -> list[int]:
        """Frames that have a label image (those with a segmentation), sorted."""
        return sorted(self._segmentations or ())

    def __call__(self, frame_index: int) -> np.ndarray:
        """(H, W) int32 global ids of one frame (0 = no mask)."""
        if self._segmentations is None:
            raise ValueError(f"{self.agent}: corrected labels need the agent's segmentations, none were given")
        if frame_index not in self._segmentations:
            raise ValueError(f"{self.agent}: no segmentation for frame {frame_index}")
        local = self._fusion.label_image(self._segmentations[frame_index])
        if local.max(initial=0) >= len(self._lut):
            raise ValueError(f"{self.agent}: frame {frame_index} has local id {local.max()} "
                             "that the fusion result does not know")
        out = self._lut[local]
        for local_id, pieces in self._split.items():
            mask = local == local_id
            if mask.any():
                out[mask] = self._split_mask(frame_index, mask, pieces)
        return out

    def _split_mask(self, frame_index: int, mask: np.ndarray, pieces: list[tuple[int, np.ndarray]]) -> np.ndarray:
        """Global id of each pixel of ``mask``: the nearest piece to its back-projected point."""
        world, valid = self._frame(frame_index).backproject_pixels(mask=mask)
        ids = np.array([g for g, _ in pieces], np.int32)
        if not valid.any():  # no depth at all: the largest piece takes the mask
            return np.full(np.count_nonzero(mask), ids[np.argmax([len(c) for _, c in pieces])], np.int32)
        full = np.zeros(mask.shape, np.int32)
        full[valid] = ids[nearest_piece(world, [c for _, c in pieces])]
        if not valid.all(where=mask):  # pixels without depth copy their nearest pixel with depth
            _, (rows, cols) = ndimage.distance_transform_edt(~valid, return_indices=True)
            full = full[rows, cols]
        return full[mask]

    def _frame(self, frame_index: int) -> Frame:
        if self._frames is None:
            raise ValueError(f"{self.agent}: frame {frame_index} holds an under-segmented instance; "
                             "splitting its mask needs the agent's frames (depth and pose), none were given")
        if self._frame_by_index is None:
            self._frame_by_index = {f.index: f for f in self._frames}
        if frame_index not in self._frame_by_index:
            raise ValueError(f"{self.agent}: frame {frame_index} is not among the agent's frames")
        return self._frame_by_index[frame_index]


LabelFunction = Callable[[int], np.ndarray]
"""frame index -> (H, W) int32 global ids."""
