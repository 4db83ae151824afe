"""One agent of a team: its frames, online fusion, mapper, and what it holds from its peers.

A member only ever shares ``messages`` with the others (no object crosses between members), so that
one process per agent can come later. Per round (``Team.round`` calls these in order):
``local_round`` (read the round's frames -> online fusion -> keyframes -> local iterations of the data
loss, eq. 8-11, plus eq. 12's consensus toward the parameters last received with ``local_consensus``),
``parameter_message`` / ``ray_message`` for the peers the plan names (``acknowledge`` books what a
delivered one gave the peer), ``receive_parameters`` (hold, align on arrival, adopt),
``consistency_round`` (eq. 12 + eq. 13).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Protocol, Sequence

import numpy as np
import torch

from mapping.agent import ExportedInstance, InstanceFrame, MappingAgent
from mapping.data.frame import Frame
from mapping.field import InstanceFieldBank, LiveRows
from mapping.fusion.online import OnlineFusion
from mapping.perception.codebook import CodeBook, CodeBookEntry
from mapping.perception.types import FrameSegmentation
from mapping.pointcloud import voxel_downsample
from mapping.team.arrival import ArrivalDecision, InstanceView, align_arrivals
from mapping.team.config import ConsistencyConfig, ExchangeConfig, TeamConfig  # noqa: F401 (re-exported)
from mapping.team.consistency import (ConsistencyPairs, consensus_penalty, dinno_dual_update, dinno_penalty,
                                      metropolis_mix)
from mapping.team.cross_rendering import (instance_render_consistency_loss, peer_render_targets, rays_of_message,
                                         render_consistency_loss)
from mapping.team.global_map import GLOBAL_INSTANCE_ID, as_global_image, global_entry
from mapping.team.messages import InstancePayload, ParameterMessage, PointCloudMessage, RayMessage
from mapping.team.report import AgentSnapshot, AlignmentCounts, ConsistencyTerms, PeerKnowledge


class AgentStream(Protocol):
    """An agent's frames in order: the simulator's renderer or a dataset, with the segmenter's masks."""

    def __len__(self) -> int: ...

    def read(self, index: int) -> tuple[Frame, FrameSegmentation]:
        """Frame ``index`` and its segmentation (caption features filled)."""
        ...


@dataclass
class Vocabulary:
    """Category names with their encoded prompts; which of them are walls, floor, ceiling."""

    names: list[str]
    features: np.ndarray  # (C, d) unit rows
    structure: frozenset[str] = frozenset({"wall", "floor", "ceiling"})

    @staticmethod
    def from_encoder(names: Sequence[str], text_encoder, structure: Sequence[str] = ("wall", "floor", "ceiling")
                     ) -> "Vocabulary":
        """Encode "a {name} in a room" for each name (the zero-shot prompt of ``evaluate.semantic``)."""
        from mapping.evaluate.semantic import category_prompts  # noqa: PLC0415

        names = list(dict.fromkeys(names))
        features = np.asarray(text_encoder.encode(category_prompts(names)), np.float32)
        features /= np.maximum(np.linalg.norm(features, axis=1, keepdims=True), 1e-12)
        return Vocabulary(names, features, frozenset(structure))

    def label(self, feature: np.ndarray) -> str:
        """The zero-shot category of a caption feature (cosine to the prompts)."""
        return self.names[int(np.argmax(self.features @ np.asarray(feature, np.float32)))]


@dataclass
class LocalReport:
    frames: list[int]
    keyframes: int
    loss: float
    """The data loss (eq. 8-11) of the last local iteration."""
    seconds: float
    parameter: float = 0.0
    """The consensus term (eq. 12) of the last local iteration (``local_consensus``; 0 without)."""


class TeamMember:
    """Agent ``index`` of a team (see the module docstring for the round's calls)."""

    def __init__(self, index: int, stream: AgentStream, config: TeamConfig, vocabulary: Vocabulary, seed: int,
                 device: str = "auto"):
        self.index, self.stream, self.config, self.vocabulary = index, stream, config, vocabulary
        self.labels: dict[int, str] = {}
        self.mapper = MappingAgent(config.mapping, is_structure=lambda iid: config.global_map
                                   or self.labels.get(iid) in vocabulary.structure,
                                   device=device, seed=seed, agent_index=index)
        self.fusion = OnlineFusion(config.fusion)
        self.next_frame = 0
        self.max_frame_read = -1
        self.meaning: dict[int, tuple[str, np.ndarray, float]] = {}  # own id -> a more confident peer's meaning
        self.held: dict[int, dict[int, InstancePayload]] = {}  # peer -> peer id -> last payload
        self.held_round: dict[int, int] = {}
        self.peer_degrees: dict[int, int] = {}  # peer -> how many peers it sent to (DSGD)
        self.matches: dict[int, dict[int, int]] = {}  # peer -> peer id -> own id
        self.sent_vectors: dict[int, dict[int, np.ndarray]] = {}
        self.sent_cloud_points: dict[int, dict[int, int]] = {}
        self.duals: dict[str, torch.Tensor] = {}
        self.peer_positions: dict[int, tuple[int, np.ndarray]] = {}  # peer -> (round, (3,) position) from its rays
        self._shadow: dict[int, tuple[int, list, list]] = {}
        self._unacknowledged: dict[int, tuple[dict, dict]] = {}  # receiver -> bookkeeping of the message in flight
        self._last_position: np.ndarray | None = None

    @property
    def name(self) -> str:
        return f"agent_{self.index}"

    @property
    def done(self) -> bool:
        return self.next_frame >= len(self.stream)

    # ---- 1-3: perceive, fuse, local iterations ---------------------------------------------------
    def read_round(self) -> tuple[list[tuple[Frame, FrameSegmentation]], float]:
        """The round's frames and their segmentations from the stream (not yet taken), with the seconds
        it took; the stream (renderer, segmenter, text encoder) is only ever called from one thread."""
        start = time.perf_counter()
        stop = min(self.next_frame + self.config.frames_per_round, len(self.stream))
        return [self.stream.read(i) for i in range(self.next_frame, stop)], time.perf_counter() - start

    def local_round(self, read: tuple[list, float] | None = None) -> LocalReport:
        """Take the round's frames (``read_round``'s result, read now when None), fuse, train."""
        read, read_s = self.read_round() if read is None else read
        start = time.perf_counter()
        stop = self.next_frame + len(read)
        self.max_frame_read = max(self.max_frame_read, stop - 1)
        indices = list(range(self.next_frame, stop))
        self.next_frame = stop
        frames, segs = [f for f, _ in read], [s for _, s in read]
        images = self.fusion.add_round(frames, segs)
        if self.config.global_map:
            images = [as_global_image(image) for image in images]
        for iid, inst in self.fusion.instances.items():
            self.labels.setdefault(iid, self.vocabulary.label(inst.caption_feature))
        keyframes = sum(self.mapper.ingest(frame, image) for frame, image in zip(frames, images))
        terms: dict[str, torch.Tensor] = {}
        extra = self._local_consensus(terms) if self.config.consistency.local_consensus else None
        loss = self.mapper.train(keyframes * self.config.mapping.iterations_per_keyframe, extra) if keyframes else 0.0
        parameter = float(terms["parameter"]) if "parameter" in terms else 0.0  # read once, not every step
        return LocalReport(indices, keyframes, loss - parameter, read_s + time.perf_counter() - start, parameter)

    def _local_consensus(self, terms: dict[str, torch.Tensor]):
        """Eq. 12's consensus term toward the parameters held from the peers, for every local iteration
        (MACIM's midpoint of my current and the peer's parameters; its value goes to
        ``terms["parameter"]``); None when nothing is paired."""
        if self.config.consistency.algorithm != "consensus":
            return None
        pairs = {name: self._pairs(name) for name in self.mapper.banks}
        if not any(len(p) for p in pairs.values()):
            return None
        rho = self.config.consistency.penalty_rho

        def penalty() -> torch.Tensor:
            total = torch.zeros((), device=self.mapper.device)
            for name, bank in self.mapper.banks.items():
                total = total + consensus_penalty(bank.params, bank.params.detach(), pairs[name], rho)
            terms["parameter"] = total.detach()  # a tensor: no device sync inside the training loop
            return total
        return penalty

    # ---- 4: messages -----------------------------------------------------------------------------
    def parameter_message(self, receiver: int, round_index: int, degree: int) -> ParameterMessage:
        """This agent's instances for ``receiver`` (what changed-only sending skips, clouds the first time
        or after they doubled); what the receiver holds is booked only on ``acknowledge``."""
        ex = self.config.exchange
        sent = dict(self.sent_vectors.get(receiver, {}))
        clouds = dict(self.sent_cloud_points.get(receiver, {}))
        payloads = []
        for iid in self.mapper.live_ids():
            if not ex.forward_adopted and not self.mapper.keyframes.has_pixels(iid):
                continue
            inst = self.mapper.export_instance(iid)
            last = sent.get(iid)
            if ex.changed_only is not None and last is not None and iid in clouds and (
                    np.linalg.norm(inst.params - last) <= ex.changed_only * max(np.linalg.norm(last), 1e-12)):
                continue
            fused = None if self.config.global_map else self.fusion.instances.get(iid)
            cloud = None
            if fused is not None and len(fused.points) and (
                    iid not in clouds or len(fused.points) >= ex.resend_cloud_growth * clouds[iid]):
                cloud = voxel_downsample(fused.points, ex.cloud_voxel_m).astype(np.float32)
                clouds[iid] = len(fused.points)
            entry = self.entry(iid)
            dtype = np.float16 if ex.float16 else np.float32
            payloads.append(InstancePayload(
                iid, inst.bank, inst.params.astype(dtype), inst.bound_lo.astype(np.float32),
                inst.bound_hi.astype(np.float32), np.asarray(inst.frame.centre, np.float32), inst.frame.half,
                inst.frame.origin, inst.frame.version, entry.caption, entry.caption_feature.astype(dtype),
                entry.confidence, cloud))
            sent[iid] = inst.params
        self._unacknowledged[receiver] = (sent, clouds)
        return ParameterMessage(self.index, receiver, round_index, payloads, degree)

    def acknowledge(self, receiver: int, delivered: bool) -> None:
        """The link told the sender whether its parameter message reached ``receiver`` (an
        acknowledgement, not counted in bytes). Only a delivered message changes what this agent
        believes the receiver holds: a lost first message with an instance's cloud is sent again with
        its cloud next time, and changed-only sending compares with what really arrived."""
        booked = self._unacknowledged.pop(receiver, None)
        if delivered and booked is not None:
            self.sent_vectors[receiver], self.sent_cloud_points[receiver] = booked

    def point_cloud_message(self, receiver: int, round_index: int) -> PointCloudMessage:
        """Every point this agent has observed so far (its fused instances' clouds), down-sampled."""
        clouds = [inst.points for inst in self.fusion.instances.values() if len(inst.points)]
        points = np.concatenate(clouds) if clouds else np.zeros((0, 3))
        voxel = self.config.exchange.cloud_voxel_m
        points = voxel_downsample(points, voxel) if len(points) else points
        return PointCloudMessage(self.index, receiver, round_index, np.asarray(points, np.float32))

    def ray_message(self, receiver: int, round_index: int, seed: int) -> RayMessage | None:
        """The poses of this round's frames (at most ``poses_per_message``) and a pixel seed."""
        if self.max_frame_read < 0:
            return None
        c = self.config.consistency
        first = max(0, self.next_frame - self.config.frames_per_round)
        if c.ray_poses == "mapped" and first > 0:  # views this agent has trained on for a round or more
            picks = np.unique(np.random.default_rng([seed, 7]).choice(first, size=min(c.poses_per_message, first),
                                                                       replace=False))
        else:
            picks = np.unique(np.linspace(first, self.next_frame - 1, c.poses_per_message).round().astype(int))
        frames = [self.stream.read(int(i))[0] for i in picks]
        k = frames[0].intrinsics
        return RayMessage(self.index, receiver, round_index, np.stack([f.pose for f in frames]).astype(np.float32),
                          (k.fx, k.fy, k.cx, k.cy, k.width, k.height), seed, c.rays_per_pose)

    # ---- 5: arrival ------------------------------------------------------------------------------
    def receive_parameters(self, message: ParameterMessage) -> AlignmentCounts:
        """Hold the peer's instances; align the newly described ones (match / merge / adopt); agree on
        frames and grow boxes for matched ones. Returns counts of what happened."""
        peer = message.sender
        held = self.held.setdefault(peer, {})
        matches = self.matches.setdefault(peer, {})
        for inst in message.instances:
            held[inst.instance_id] = inst
        self.held_round[peer] = message.round
        self.peer_degrees[peer] = message.degree
        counts = AlignmentCounts()
        if self.config.global_map:
            return self._receive_global(message)
        new = {i.instance_id: i for i in message.instances if i.cloud is not None and i.instance_id not in matches}
        if self.config.alignment:
            own = {iid: InstanceView(inst.points, inst.caption_feature, inst.confidence)
                   for iid, inst in self.fusion.instances.items()}
            arrived = {pid: InstanceView(p.cloud.astype(np.float64), p.caption_feature.astype(np.float32),
                                         p.confidence) for pid, p in new.items()}
            decisions = align_arrivals(own, arrived, self.config.arrival)
        else:
            decisions = [ArrivalDecision(pid, "adopt") for pid in sorted(new)]
        for d in decisions:
            payload = new[d.peer_id]
            if d.kind == "adopt":
                own_id = self.fusion.add_instance(payload.cloud.astype(np.float64), payload.caption,
                                                  payload.caption_feature.astype(np.float32), payload.confidence)
                self.labels[own_id] = self.vocabulary.label(payload.caption_feature.astype(np.float32))
                self.mapper.adopt_instance(own_id, _exported(payload))
                counts.adopted += 1
            else:
                own_id = d.own_id
                for piece in d.merged:
                    self._merge(piece, own_id)
                    counts.merged += 1
                if own_id not in self.mapper.slots:  # seen in a non-keyframe only: start from the peer's network
                    self.mapper.adopt_instance(own_id, _exported(payload))
                if d.take_meaning:
                    self.meaning[own_id] = (payload.caption, payload.caption_feature.astype(np.float32),
                                            payload.confidence)
                counts.matched += 1
            matches[d.peer_id] = own_id
        frames = {}
        for inst in message.instances:
            own_id = matches.get(inst.instance_id)
            frame = self._agree(own_id, inst)
            if frame is not None:
                frames[own_id] = frame
        if frames:
            self.mapper.set_frames(frames)  # one batched refit per bank
        counts.refit = len(frames)
        return counts

    def _receive_global(self, message: ParameterMessage) -> AlignmentCounts:
        """Global maps share one frame (the scene box): the peer's network is this agent's global
        instance, matched at once, or adopted when this agent has not mapped anything yet. Like a
        matched instance, the global map's box then covers the peer's box too (every message, since
        the peer's box grows as it explores): the map is meshed and cross-rendered inside its box, so
        without this an agent's map would stop where its own frames did."""
        from mapping.bounds import InstanceBound  # noqa: PLC0415

        matches = self.matches.setdefault(message.sender, {})
        counts = AlignmentCounts()
        for inst in message.instances:
            if inst.instance_id not in matches:
                if GLOBAL_INSTANCE_ID not in self.mapper.slots:
                    self.mapper.adopt_instance(GLOBAL_INSTANCE_ID, _exported(inst))
                    counts.adopted += 1
                else:
                    counts.matched += 1
                matches[inst.instance_id] = GLOBAL_INSTANCE_ID
            self.mapper.grow_bound(GLOBAL_INSTANCE_ID, InstanceBound(inst.bound_lo.astype(np.float64),
                                                                     inst.bound_hi.astype(np.float64)))
        return counts

    def _merge(self, piece: int, target: int) -> None:
        if piece in self.fusion.instances and target in self.fusion.instances:
            self.fusion.merge(piece, target)
        if piece in self.mapper.slots and target in self.fusion.instances:  # a retired id keeps no network
            self.mapper.merge_instances(piece, target)
        for table in self.matches.values():
            for pid, own in table.items():
                if own == piece:
                    table[pid] = target

    def _agree(self, own_id: int | None, payload: InstancePayload) -> InstanceFrame | None:
        """A matched instance covers the peer's box too; returns the frame it must move to so that both
        sides converge on one frame (None: it keeps its own)."""
        slot = self.mapper.slots.get(own_id) if own_id is not None else None
        if slot is None or not slot.alive or slot.bank != payload.bank:
            return None
        from mapping.bounds import InstanceBound  # noqa: PLC0415

        self.mapper.grow_bound(own_id, InstanceBound(payload.bound_lo.astype(np.float64),
                                                     payload.bound_hi.astype(np.float64)))
        theirs = _frame(payload)
        mine = self.mapper.frame_of(own_id)
        if theirs.same_as(mine) or not theirs.better_than(mine):
            return None
        bank = self.mapper.banks[slot.bank]
        c, h = torch.tensor(theirs.centre, device=bank.device), theirs.half
        lo, hi = bank.bound_min[slot.row], bank.bound_max[slot.row]
        coverage = float(torch.maximum((lo - c).abs(), (hi - c).abs()).max()) / h
        if coverage > self.config.mapping.frame_limit:  # my box does not fit: enlarge, keep its provenance
            centre, half = bank.default_frame(lo[None], hi[None])
            c = centre[0].tolist()
            theirs = InstanceFrame((c[0], c[1], c[2]), float(half[0]), theirs.origin, theirs.version + 1)
        return theirs

    def note_rays(self, message: RayMessage) -> None:
        """A ray message arrived: its last pose is where its sender was (all a member knows of its peers'
        positions)."""
        self.peer_positions[message.sender] = (message.round, np.asarray(message.poses[-1][:3, 3], np.float64))

    # ---- 6: consistency iterations ---------------------------------------------------------------
    def consistency_round(self, ray_messages: Sequence[RayMessage]) -> ConsistencyTerms:
        """Data loss + parameter consistency (eq. 12) + render consistency (eq. 13) iterations."""
        c = self.config.consistency
        start = time.perf_counter()
        pairs = {name: self._pairs(name) for name in self.mapper.banks}
        anchors = {name: bank.params.detach().clone() for name, bank in self.mapper.banks.items()}
        if c.algorithm == "dinno":
            for name, bank in self.mapper.banks.items():
                dual = self.duals.get(name)
                if dual is None or dual.shape != bank.params.shape:
                    grown = torch.zeros_like(bank.params.detach())
                    if dual is not None:
                        grown[:len(dual)] = dual
                    dual = grown
                self.duals[name] = dinno_dual_update(dual, bank.params, pairs[name], c.penalty_rho)
        elif c.algorithm == "dsgd":
            for name, bank in self.mapper.banks.items():
                with torch.no_grad():
                    bank.params.copy_(metropolis_mix(bank.params, pairs[name]))
        rays = [rays_of_message(m, self.mapper.device) for m in ray_messages if m.sender in self.held] \
            if c.cross_rendering else []
        senders = [m.sender for m in ray_messages if m.sender in self.held] if c.cross_rendering else []
        terms = ConsistencyTerms()
        n_pairs = sum(len(p) for p in pairs.values())
        if n_pairs == 0 and not rays:
            terms.seconds = time.perf_counter() - start
            return terms

        own_fields, own_labels = self._own_fields()
        observed = self.mapper.keyframes.observes if c.blind_zones_only else None
        weights = replace(self.config.mapping.loss_weights, colour=0.0, depth_uncertainty=c.render_depth_uncertainty)
        instance_form = c.cross_rendering_form == "instance"
        # the peers' renderings do not change within the round: once per sender
        targets = [peer_render_targets(*self._peer_fields(sender), bundle, self.matches.get(sender, {}),
                                       own_fields if instance_form else None, observed, c.samples_per_box,
                                       surface_eps_m=self.config.mapping.sampler.surface_eps_m)
                   for sender, bundle in zip(senders, rays)]

        def extra() -> torch.Tensor:
            total = torch.zeros((), device=self.mapper.device)
            for name, bank in self.mapper.banks.items():
                if c.algorithm == "consensus":
                    total = total + consensus_penalty(bank.params, anchors[name], pairs[name], c.penalty_rho)
                elif c.algorithm == "dinno":
                    total = total + dinno_penalty(bank.params, anchors[name], self.duals[name], pairs[name], c.penalty_rho)
            terms.parameter = float(total.detach())
            render = torch.zeros((), device=self.mapper.device)
            used = 0
            for target in targets:
                if instance_form:
                    loss = instance_render_consistency_loss(own_fields, own_labels, target, self.config.mapping.sampler,
                                                            weights, self.mapper.generator)
                else:
                    loss = render_consistency_loss(own_fields, target, c.samples_per_box, c.free_space_weight)
                render, used = render + loss, used + len(target)
            terms.render, terms.render_rays = float(render.detach()), used
            return total + c.render_weight * render

        terms.loss = self.mapper.train(c.iterations, extra) if c.iterations else 0.0
        terms.pairs, terms.seconds = n_pairs, time.perf_counter() - start
        return terms

    def _pairs(self, bank_name: str) -> ConsistencyPairs:
        """(own row, peer vector) of every instance both hold in one frame, one peer vector per own row
        and peer (the peer's instance with the largest box when several match one of mine)."""
        rows, vectors, peers, by_row = [], [], [], {}
        bank = self.mapper.banks[bank_name]
        chosen: dict[tuple[int, int], InstancePayload] = {}
        for peer, table in self.matches.items():
            for pid, own in table.items():
                slot = self.mapper.slots.get(own)
                payload = self.held.get(peer, {}).get(pid)
                if slot is None or payload is None or not slot.alive or slot.bank != bank_name:
                    continue
                if not _frame(payload).same_as(self.mapper.frame_of(own)):
                    continue
                key = (peer, own)
                size = float(np.prod(payload.bound_hi - payload.bound_lo))
                if key not in chosen or size > float(np.prod(chosen[key].bound_hi - chosen[key].bound_lo)):
                    chosen[key] = payload
        for (peer, own), payload in sorted(chosen.items()):
            row = self.mapper.slots[own].row
            rows.append(row)
            vectors.append(torch.as_tensor(payload.params.astype(np.float32)))
            peers.append(self.peer_degrees.get(peer, 1))
            by_row[row] = by_row.get(row, 0) + 1
        dev = bank.device
        if not rows:
            empty = torch.zeros(0, dtype=torch.long, device=dev)
            return ConsistencyPairs(empty, torch.zeros(0, bank.param_dim, device=dev), empty, empty)
        return ConsistencyPairs(torch.as_tensor(rows, device=dev), torch.stack(vectors).to(dev),
                                torch.as_tensor(peers, device=dev), torch.as_tensor([by_row[r] for r in rows], device=dev))

    def _own_fields(self) -> tuple[list[LiveRows], list[torch.Tensor]]:
        """My live instances per bank, and the instance id of each of their rows."""
        fields, labels = [], []
        for name, bank in self.mapper.banks.items():
            live = sorted((s.row, iid) for iid, s in self.mapper.slots.items() if s.bank == name and s.alive)
            if live:
                fields.append(LiveRows(bank, [row for row, _ in live]))
                labels.append(torch.as_tensor([iid for _, iid in live], dtype=torch.long, device=bank.device))
        return fields, labels

    def _peer_fields(self, peer: int) -> tuple[list[InstanceFieldBank], list[torch.Tensor]]:
        """The peer's map as I hold it (its last parameters), rebuilt when new ones came in, and the
        peer's instance id of each row."""
        key = self.held_round.get(peer, -1)
        cached = self._shadow.get(peer)
        if cached is not None and cached[0] == key:
            return cached[1], cached[2]
        fields, labels = [], []
        for name, own_bank in self.mapper.banks.items():
            items = [p for p in self.held.get(peer, {}).values() if p.bank == name]
            if not items:
                continue
            bank = InstanceFieldBank(own_bank.config, own_bank.device)
            bank.add_instances(len(items), torch.as_tensor(np.stack([p.bound_lo for p in items])),
                               torch.as_tensor(np.stack([p.bound_hi for p in items])),
                               frame_centre=torch.as_tensor(np.stack([p.frame_centre for p in items])),
                               frame_half=torch.as_tensor([p.frame_half for p in items]),
                               params=torch.as_tensor(np.stack([p.params.astype(np.float32) for p in items])))
            bank.requires_grad_(False)
            fields.append(bank)
            labels.append(torch.as_tensor([p.instance_id for p in items], dtype=torch.long, device=own_bank.device))
        self._shadow[peer] = (key, fields, labels)
        return fields, labels

    # ---- what this agent knows ---------------------------------------------------------------------
    def snapshot(self, rounds: int, new_frames: Sequence[Frame], budget_left_bytes: float,
                 bytes_sent_total: int) -> AgentSnapshot:
        """This agent's own knowledge now (``new_frames``: what it read in the last round; the budget and
        byte count come from its side of the channel)."""
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
        return AgentSnapshot(self.index, rounds, self.next_frame, tuple(new_frames), position, len(live), own, peers,
                             float(budget_left_bytes), int(bytes_sent_total))

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


def _frame(payload: InstancePayload) -> InstanceFrame:
    c = [float(x) for x in payload.frame_centre]
    return InstanceFrame((c[0], c[1], c[2]), float(payload.frame_half), int(payload.frame_origin),
                         int(payload.frame_version))


def _exported(payload: InstancePayload) -> ExportedInstance:
    return ExportedInstance(payload.instance_id, payload.bank, payload.params.astype(np.float32),
                            payload.bound_lo.astype(np.float64), payload.bound_hi.astype(np.float64), _frame(payload))
