"""One agent of a team: its frames, online fusion, mapper, and what it holds from its peers. What it sends
is in ``outbox``, what it does with arrivals in ``inbox``, eq. 12 and 13 in ``agreement`` (mixins of
``TeamMember`` over this state).

A member only ever shares ``messages`` with the others (no object crosses between members), so that
one process per agent can come later. Per round (``Team.round`` calls these in order):
``local_round`` (read the round's frames -> online fusion -> keyframes -> local iterations of the data
loss, eq. 8-11, plus eq. 12's consensus toward the parameters last received with ``local_consensus``),
``parameter_message`` / ``ray_message`` for the peers the plan names (``acknowledge`` books what a
delivered one gave the peer), ``receive_parameters`` (hold, align on arrival, adopt),
``degree_messages`` (DSGD only: its pairs and degrees for each peer), ``consistency_round`` (eq. 12 + eq. 13).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Callable, Protocol, Sequence

import numpy as np
import torch

from mapping.model.agent import MappingAgent
from mapping.model.observed import ObservedSpace
from mapping.data.frame import Frame
from mapping.fusion.online import OnlineFusion
from mapping.perception.codebook import CodeBook, CodeBookEntry
from mapping.perception.types import FrameSegmentation
from mapping.perception.vocabulary import Vocabulary
from mapping.team.agreement import Agreement, PenaltyReading
from mapping.team.config import TeamConfig
from mapping.team.codec import vector_wire_bytes
from mapping.team.consistency import PairKey
from mapping.team.global_map import as_global_image, global_entry
from mapping.team.inbox import Inbox
from mapping.team.messages import InstancePayload
from mapping.team.outbox import Outbox
from mapping.team.report import AgentSnapshot, InstanceOnLink, LinkState, PeerKnowledge, priority_order
from mapping.model.topdown import ColumnGrid, ColumnMap, column_map


class AgentStream(Protocol):
    """An agent's frames in order: the simulator's renderer or a dataset, with the segmenter's masks."""

    def __len__(self) -> int: ...

    def read(self, index: int) -> tuple[Frame, FrameSegmentation]:
        """Frame ``index`` and its segmentation (caption features filled)."""
        ...


@dataclass
class LocalReport:
    frames: list[int]
    keyframes: int
    loss: float
    """The data loss (eq. 8-11) of the last local iteration."""
    seconds: float
    parameter: float = 0.0
    """The consensus term (eq. 12) of the last local iteration (``local_consensus``; 0 without)."""


@dataclass
class LocalWork:
    """A local round between fusion and training (``TeamMember.prepare_local``): how many iterations
    to train and the extra term (eq. 12's local consensus) each adds to the data loss."""

    frames: list[int]
    keyframes: int
    iterations: int
    extra: Callable[[], torch.Tensor] | None
    reading: PenaltyReading
    seconds: float
    """Its own compute time so far (reading, fusion, keyframes)."""


class StreamReader:
    """An agent's stream and how far it has read it: the part of a member that stays with the streams
    (``TeamMember`` here, ``mapping.team.remote.RemoteMember`` on the driver of a member in a process)."""

    index: int
    stream: AgentStream
    config: TeamConfig
    next_frame: int

    @property
    def name(self) -> str:
        return f"agent_{self.index}"

    @property
    def done(self) -> bool:
        return self.next_frame >= len(self.stream)

    def read_round(self) -> tuple[list[tuple[Frame, FrameSegmentation]], float]:
        """The round's frames and their segmentations from the stream (not yet taken), with the seconds
        it took; the stream (renderer, segmenter, text encoder) is only ever called from one thread."""
        start = time.perf_counter()
        stop = min(self.next_frame + self.config.frames_per_round, len(self.stream))
        return [self.stream.read(i) for i in range(self.next_frame, stop)], time.perf_counter() - start


@dataclass(frozen=True)
class StructureTest:
    """Whether an instance is a wall, floor or ceiling (the mapper's wider networks), by its member's labels.

    It holds the member's label dict itself, not the member: a member then holds no reference cycle (a
    reset frees the old team by reference counting, with no full garbage collection) and still pickles
    whole into and out of a Ray process."""

    labels: dict[int, str]
    structure: frozenset[str]
    global_map: bool

    def __call__(self, iid: int) -> bool:
        return self.global_map or self.labels.get(iid) in self.structure


class TeamMember(StreamReader, Outbox, Inbox, Agreement):
    """Agent ``index`` of a team (see the module docstring for the round's calls)."""

    def __init__(self, index: int, stream: AgentStream, config: TeamConfig, vocabulary: Vocabulary, seed: int,
                 device: str = "auto", init_seed: int | None = None):
        self.index, self.stream, self.config, self.vocabulary = index, stream, config, vocabulary
        self._labels: dict[int, str] = {}
        mapping = config.mapping
        if (every := config.keyframe_every(len(stream))) != mapping.keyframe_every:
            mapping = replace(mapping, keyframe_every=every)  # a short stream: keyframes more often
        if config.global_map and mapping.observed_cell_m is not None:
            mapping = replace(mapping, observed_cell_m=None)  # one scene network: the baselines mesh as published
        self.mapper = MappingAgent(mapping, is_structure=StructureTest(self._labels, vocabulary.structure,
                                                                       config.global_map),
                                   device=device, seed=seed, agent_index=index, init_seed=init_seed)
        self.fusion = OnlineFusion(config.fusion)
        self.next_frame = 0
        self.max_frame_read = -1
        self.meaning: dict[int, tuple[str, np.ndarray, float]] = {}  # own id -> a more confident peer's meaning
        self.held: dict[int, dict[int, InstancePayload]] = {}  # peer -> peer id -> last payload
        self.held_round: dict[int, int] = {}  # peer -> round its last parameter message arrived
        self.held_at: dict[int, dict[int, int]] = {}  # peer -> peer id -> round that instance's vector arrived
        self.matches: dict[int, dict[int, int]] = {}  # peer -> peer id -> own id
        self.sent_vectors: dict[int, dict[int, np.ndarray]] = {}
        self.sent_cloud_points: dict[int, dict[int, int]] = {}
        self.sent_rounds: dict[int, dict[int, int]] = {}  # peer -> own id -> round its vector last reached the peer
        self.sent_features: dict[int, dict[int, np.ndarray]] = {}  # peer -> own id -> its caption feature there (codec)
        self.sent_observed: dict[int, dict[int, ObservedSpace]] = {}  # peer -> own id -> its observed space there (codec)
        self.duals: dict[str, torch.Tensor] = {}
        self.mixing_weights: dict[PairKey, float] = {}  # DSGD: the weight W_kj of each edge mixed last round
        self.peer_positions: dict[int, tuple[int, np.ndarray]] = {}  # peer -> (round, (3,) position) from its rays
        self._shadow: dict[int, tuple[int, list, list]] = {}
        self._unacknowledged: dict[int, tuple[dict, dict, dict, dict, dict]] = {}  # receiver -> bookkeeping of the message in flight
        self.delivered_round: dict[str, dict[int, int]] = {"params": {}, "rays": {}, "points": {}}  # kind -> peer -> round
        self._last_position: np.ndarray | None = None
        self.born_round: dict[int, int] = {}  # own id -> round it first appeared in a snapshot of this map
        self.round_seen = 0

    @property
    def labels(self) -> dict[int, str]:
        """Own instance id -> category label. Edited in place, never replaced: the mapper's
        ``StructureTest`` holds this very dict."""
        return self._labels

    # ---- 1-3: perceive, fuse, local iterations ---------------------------------------------------
    def local_round(self, read: tuple[list, float] | None = None) -> LocalReport:
        """Take the round's frames (``read_round``'s result, read now when None), fuse, train."""
        work = self.prepare_local(read)
        start = time.perf_counter()
        loss = self.mapper.train(work.iterations, work.extra) if work.iterations else 0.0
        return self.finish_local(work, loss, time.perf_counter() - start)

    def prepare_local(self, read: tuple[list, float] | None = None) -> LocalWork:
        """``local_round`` up to its training: take the frames, fuse, make keyframes; what to train."""
        read, read_s = self.read_round() if read is None else read
        start = time.perf_counter()
        stop = self.next_frame + len(read)
        self.max_frame_read = max(self.max_frame_read, stop - 1)
        indices = list(range(self.next_frame, stop))
        self.next_frame = stop
        kept = [pair for i, pair in zip(indices, read) if not self.config.held_out(i)]
        frames, segs = [f for f, _ in kept], [s for _, s in kept]
        images = self.fusion.add_round(frames, segs)
        if self.config.global_map:
            images = [as_global_image(image) for image in images]
        for iid, inst in self.fusion.instances.items():
            self.labels.setdefault(iid, self.vocabulary.label(inst.caption_feature))
        first = self.mapper.keyframes.seen == 0
        keyframes = sum(self.mapper.ingest(frame, image) for frame, image in zip(frames, images))
        reading = PenaltyReading()
        extra = self.local_consensus(reading) if self.config.consistency.local_consensus else None
        iterations = keyframes * self.config.mapping.iterations_per_keyframe
        if first and keyframes:  # the map's first keyframe (MACIM: 200 iterations on its first frame)
            iterations += self.config.mapping.iterations_first_keyframe
        # a short stream trains the rest once, in the round that read its last frame (a finished member's
        # later rounds read nothing, and a team resumed after this round is past it)
        if indices and self.done:
            iterations += self.steps_after_stream()
        return LocalWork(indices, keyframes, iterations, extra, reading, read_s + time.perf_counter() - start)

    def finish_local(self, work: LocalWork, loss: float, train_s: float) -> LocalReport:
        """The round's report once its ``work.iterations`` were trained (``loss``: the last one's total)."""
        parameter = work.reading.read()  # read once, not every step
        return LocalReport(work.frames, work.keyframes, loss - parameter, work.seconds + train_s, parameter)

    def steps_after_stream(self) -> int:
        """Local iterations its keyframes give short of ``TeamConfig.min_local_steps`` (each keyframe gives
        ``iterations_per_keyframe``), plus ``MappingConfig.iterations_after_stream``: what it trains after
        its last frame."""
        had = self.mapper.keyframes.seen * self.config.mapping.iterations_per_keyframe
        return max(0, self.config.min_local_steps - had) + self.config.mapping.iterations_after_stream

    # ---- what this agent knows ---------------------------------------------------------------------
    def snapshot(self, rounds: int, new_frames: Sequence[Frame], budget_left_bytes: float,
                 link_bytes: np.ndarray) -> AgentSnapshot:
        """This agent's own knowledge now (``new_frames``: what it read in the last round; the budget and
        the (N,) bytes it sent to each agent come from its side of the channel)."""
        peers = {}
        for peer, table in self.held.items():
            boxes = tuple((p.bound_lo, p.bound_hi) for p in table.values() if p.bank == "object")
            peers[peer] = PeerKnowledge(len(table), boxes, self.held_round.get(peer), self.peer_positions.get(peer))
        for peer, position in self.peer_positions.items():
            if peer not in peers:
                peers[peer] = PeerKnowledge(0, (), None, position)
        live = self.mapper.live_ids()
        own = sum(1 for iid in live if self.mapper.keyframes.has_pixels(iid))
        position = np.asarray(new_frames[-1].pose[:3, 3], np.float64) if new_frames else self._last_position
        self._last_position = position
        link_bytes = np.asarray(link_bytes)
        self.round_seen = rounds
        links, instance_links, map_bytes = self.link_states(link_bytes)
        return AgentSnapshot(self.index, rounds, self.next_frame, tuple(new_frames), position, len(live), own, peers,
                             float(budget_left_bytes), int(link_bytes.sum()), links=links, frames_total=len(self.stream),
                             instance_links=instance_links, map_bytes=map_bytes)

    def link_states(self, link_bytes: np.ndarray) -> tuple[dict[int, LinkState], dict[int, tuple[InstanceOnLink, ...]], int]:
        """Its side of the link to each peer (``link_bytes[j]``: bytes sent to j): how far each peer's copy
        of its shareable instances is from their parameters now, and when messages last reached it; the same
        per instance (``InstanceOnLink``, in ``priority_order``); and the wire bytes of all its vectors."""
        tolerance = self.config.exchange.up_to_date_tolerance
        exported = {iid: self.mapper.export_instance(iid) for iid in self.shareable_ids()}
        current = {iid: inst.params for iid, inst in exported.items()}
        for iid in current:
            self.born_round.setdefault(iid, self.round_seen)
        states, per_instance = {}, {}
        for peer in (j for j in range(len(link_bytes)) if j != self.index):
            held = self.sent_vectors.get(peer, {})
            changes = [min(1.0, float(np.linalg.norm(p - held[iid]) / max(np.linalg.norm(held[iid]), 1e-12)))
                       if iid in held else 1.0 for iid, p in current.items()]
            count = max(len(changes), 1)
            states[peer] = LinkState(
                holds=sum(iid in held for iid in current) / count,
                up_to_date=sum(c <= tolerance for c in changes) / count if changes else 0.0,
                change=float(np.mean(changes)) if changes else 0.0,
                params_round=self.delivered_round["params"].get(peer, self.delivered_round["points"].get(peer)),
                rays_round=self.delivered_round["rays"].get(peer), bytes_sent=int(link_bytes[peer]))
            shared = set(self.matches.get(peer, {}).values())
            rounds = self.sent_rounds.get(peer, {})
            per_instance[peer] = tuple(priority_order([InstanceOnLink(
                iid, iid not in held, change, rounds.get(iid), iid in shared, self.confidence_of(iid),
                float(np.linalg.norm(exported[iid].bound_hi - exported[iid].bound_lo)), self.born_round[iid],
                self.vector_wire_bytes(exported[iid].params.size, iid in held)) for iid, change in zip(current, changes)]))
        return states, per_instance, sum(self.vector_wire_bytes(p.size, False) for p in current.values())

    def vector_wire_bytes(self, length: int, has_copy: bool) -> int:
        """Bytes one network vector of ``length`` values takes in a message: float32 or float16 whole, or as the
        codec writes it (a delta's kept share when the peer holds a copy)."""
        return vector_wire_bytes(self.config.exchange, length, has_copy)

    def confidence_of(self, iid: int) -> float:
        """The instance's confidence (eq. 1-2; a peer's when alignment gave it a more confident meaning)."""
        try:
            return float(self.entry(iid).confidence)
        except KeyError:
            return 0.0

    def surface_coverage(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Which surface samples its map reproduces (``mapping.evaluate.probe``; the reward's view)."""
        from mapping.evaluate.probe import surface_probe_coverage  # noqa: PLC0415

        return surface_probe_coverage(self.mapper, points, normals)

    def column_map(self, grid: ColumnGrid) -> ColumnMap:
        """Its map read on the columns of ``grid`` (``mapping.model.topdown.column_map``; the observation's view)."""
        return column_map(self.mapper, grid)

    # ---- outputs ---------------------------------------------------------------------------------
    def entry(self, iid: int) -> CodeBookEntry:
        """The instance's code-book entry (a more confident peer's meaning when alignment gave one)."""
        if self.config.global_map:
            return global_entry(self.vocabulary.features.shape[1])
        inst = self.fusion.instances.get(iid)
        if iid in self.meaning:
            caption, feature, confidence = self.meaning[iid]
            return CodeBookEntry(caption, feature, None, max(confidence, inst.confidence if inst else 0.0))
        if inst is None:
            raise KeyError(f"{self.name} has no instance {iid}")
        return CodeBookEntry(inst.caption, inst.caption_feature, None, inst.confidence)

    def codebook(self) -> CodeBook:
        """Instance id -> entry of the live instances (empty for a global map: it has no instances)."""
        if self.config.global_map:
            return CodeBook({})
        return CodeBook({iid: self.entry(iid) for iid in self.mapper.live_ids() if iid in self.fusion.instances})
