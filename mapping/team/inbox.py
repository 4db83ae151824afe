"""What a team member does with what arrives (step 5 of a round): it holds the peer's instances, aligns
the newly described ones over the Instance Collaborative Graph (match, merge, or adopt an instance it
never saw), agrees with the peer on each matched instance's frame and grows its box; ray messages tell
it where the peer was.

A mixin of ``TeamMember``: the state it reads and writes is the member's (``mapping.team.member``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from mapping.model.instances import ExportedInstance, InstanceFrame
from mapping.model.bounds import InstanceBound
from mapping.team.arrival import ArrivalDecision, InstanceView, align_arrivals
from mapping.team.global_map import GLOBAL_INSTANCE_ID
from mapping.team.messages import InstancePayload, ParameterMessage, RayMessage
from mapping.team.report import AlignmentCounts


class Inbox:
    """Arrival of parameter and ray messages at a ``TeamMember``."""

    def receive_parameters(self, message: ParameterMessage) -> AlignmentCounts:
        """Hold the peer's instances; align the newly described ones (match / merge / adopt); agree on
        frames and grow boxes for matched ones. Returns counts of what happened."""
        peer = message.sender
        held, held_at = self.held.setdefault(peer, {}), self.held_at.setdefault(peer, {})
        matches = self.matches.setdefault(peer, {})
        message = replace(message, instances=[resolved_payload(inst, held.get(inst.instance_id))
                                              for inst in message.instances])
        for inst in message.instances:
            held[inst.instance_id] = inst
            held_at[inst.instance_id] = message.round
        self.held_round[peer] = message.round
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
                self.mapper.adopt_instance(own_id, exported_instance(payload))
                counts.adopted += 1
            else:
                own_id = d.own_id
                for piece in d.merged:
                    self._merge(piece, own_id)
                    counts.merged += 1
                if own_id not in self.mapper.slots:  # seen in a non-keyframe only: start from the peer's network
                    self.mapper.adopt_instance(own_id, exported_instance(payload))
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

    def arrival_problem(self, message: ParameterMessage) -> str | None:
        """Why a coded message cannot be applied here, or None: a delta to a copy this agent does not hold
        (another round's, or none), or a feature left out that it never received. Checked when the message
        arrives, before its sender is told it was delivered: refused, both ends stay on the last copy."""
        if not isinstance(message, ParameterMessage):
            return None
        held, held_at = self.held.get(message.sender, {}), self.held_at.get(message.sender, {})
        for inst in message.instances:
            base = None if inst.params_code is None else inst.params_code.base
            if base is not None and (inst.instance_id not in held or held_at.get(inst.instance_id) != base):
                return (f"instance {inst.instance_id}: a delta to its copy of round {base}, this agent holds "
                        f"{'none' if inst.instance_id not in held else 'round ' + str(held_at.get(inst.instance_id))}")
            if (inst.caption_feature is None or inst.observed_code is not None) and inst.instance_id not in held:
                return (f"instance {inst.instance_id}: its {'feature' if inst.caption_feature is None else 'observed space'}"
                        " was left out, this agent never received it")
            problem = _copy_problem(inst, held.get(inst.instance_id))
            if problem is not None:
                return f"instance {inst.instance_id}: {problem}"
        return None

    def _receive_global(self, message: ParameterMessage) -> AlignmentCounts:
        """Global maps share one frame (the scene box): the peer's network is this agent's global
        instance, matched at once, or adopted when this agent has not mapped anything yet. Like a
        matched instance, the global map's box then covers the peer's box too (every message, since
        the peer's box grows as it explores): the map is meshed and cross-rendered inside its box, so
        without this an agent's map would stop where its own frames did."""
        matches = self.matches.setdefault(message.sender, {})
        counts = AlignmentCounts()
        for inst in message.instances:
            if inst.instance_id not in matches:
                if GLOBAL_INSTANCE_ID not in self.mapper.slots:
                    self.mapper.adopt_instance(GLOBAL_INSTANCE_ID, exported_instance(inst))
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
        self.mapper.grow_bound(own_id, InstanceBound(payload.bound_lo.astype(np.float64),
                                                     payload.bound_hi.astype(np.float64)))
        self.mapper.observed.add(own_id, payload.observed)  # where the peer looked counts as looked at
        theirs = payload_frame(payload)
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


def _copy_problem(payload: InstancePayload, copy: InstancePayload | None) -> str | None:
    """Why ``payload`` cannot be resolved against ``copy`` (checked before it is), or None: a delta to a copy
    of another bank or length, or that would not be finite; an observed space left out or changed where the copy
    has none, or a change whose grid does not hold the copy's."""
    if copy is None:
        return None
    if payload.params_code is not None and payload.params_code.base is not None:
        if copy.bank != payload.bank or len(copy.params) != len(payload.params):
            return f"a delta of a {payload.bank} vector of {len(payload.params)} values to a {copy.bank} copy of " \
                   f"{len(copy.params)}"
        if not np.all(np.isfinite(np.asarray(copy.params, np.float32) + payload.params)):
            return "a delta that makes its copy not finite"
    if payload.observed_code is not None and copy.observed is None:
        return "an observed space left out or changed, and this agent holds none of it"
    if payload.observed_code == "delta":
        space, held = payload.observed, copy.observed
        at = (held.origin - space.origin).tolist()
        if held.cell_m != space.cell_m or min(at) < 0 or any(
                a + n > m for a, n, m in zip(at, held.states.shape, space.states.shape)):
            return "a change to an observed space whose grid does not hold this agent's copy"
    return None


def resolved_payload(payload: InstancePayload, copy: InstancePayload | None) -> InstancePayload:
    """``payload`` as the receiver holds it: a delta added to its ``copy``'s vector (float32, the sender's
    arithmetic), a left-out feature taken from the copy, the codes dropped (``arrival_problem`` checked first)."""
    if payload.params_code is None and payload.caption_feature is not None and payload.observed_code is None \
            and payload.cloud_code is None:
        return payload
    params = payload.params
    if payload.params_code is not None and payload.params_code.base is not None:
        params = (np.asarray(copy.params, np.float32) + params).astype(np.float32)
    feature = copy.caption_feature if payload.caption_feature is None else payload.caption_feature
    observed = payload.observed
    if payload.observed_code == "held":
        observed = copy.observed
    elif payload.observed_code == "delta":  # cells only rise: the copy's maximum with the change is the space
        observed = copy.observed.copy()
        observed.merge(payload.observed)
    return replace(payload, params=params, caption_feature=feature, observed=observed, params_code=None,
                   feature_code=None, cloud_code=None, observed_code=None)


def payload_frame(payload: InstancePayload) -> InstanceFrame:
    c = [float(x) for x in payload.frame_centre]
    return InstanceFrame((c[0], c[1], c[2]), float(payload.frame_half), int(payload.frame_origin),
                         int(payload.frame_version))


def exported_instance(payload: InstancePayload) -> ExportedInstance:
    return ExportedInstance(payload.instance_id, payload.bank, payload.params.astype(np.float32),
                            payload.bound_lo.astype(np.float64), payload.bound_hi.astype(np.float64), payload_frame(payload),
                            payload.observed)
