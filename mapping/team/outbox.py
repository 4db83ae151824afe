"""What a team member sends (step 4 of a round): its parameter messages (per instance: network vector,
box, frame, code-book entry; the down-sampled cloud the first time or after it doubled), point-cloud
messages (Table VI's alternative) and ray messages (its mapped views' poses and a pixel seed, eq. 13).
What a peer holds is booked only when the link acknowledges delivery (``acknowledge``).

A mixin of ``TeamMember``: the state it reads and writes is the member's (``mapping.team.member``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from mapping.pointcloud import voxel_downsample
from mapping.team.codec import CodedCloud, CodedVector, encode_cloud, encode_vector, observed_change
from mapping.team.messages import InstancePayload, ParameterMessage, PointCloudMessage, RayMessage, to_bytes


class Outbox:
    """Message building and delivery bookkeeping of a ``TeamMember``."""

    def parameter_message(self, receiver: int, round_index: int, degree: int, only: Sequence[int] | None = None,
                          max_bytes: float | None = None, new: bool = False) -> ParameterMessage | None:
        """This agent's instances for ``receiver``: those of ``only`` (None: every shareable one), with ``new``
        also those that appeared after its last snapshot (no observation showed them yet), that changed-only
        sending does not skip, clouds the first time or after they doubled; what the receiver holds is booked
        only on ``acknowledge``. ``max_bytes`` (a link's room this round) keeps the instances that fit, in
        ``instance_priority`` order (lacked first, then the oldest copies: not the observation's slot order, which
        ranks by change); None when not even an empty message fits, or a choice (``only``) keeps nothing."""
        ex = self.config.exchange
        sent = dict(self.sent_vectors.get(receiver, {}))
        clouds = dict(self.sent_cloud_points.get(receiver, {}))
        features = dict(self.sent_features.get(receiver, {}))
        observed = dict(self.sent_observed.get(receiver, {}))
        rounds = dict(self.sent_rounds.get(receiver, {}))
        chosen = None if only is None else {int(i) for i in only}
        ids = [iid for iid in self.shareable_ids()
               if chosen is None or iid in chosen or (new and iid not in self.born_round)]
        if chosen is not None and not ids:
            return None
        payloads = []
        for iid in ids:
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
            entry = self.entry(iid)
            points = None if cloud is None else len(fused.points)
            box = (inst.bound_lo.astype(np.float32), inst.bound_hi.astype(np.float32),
                   np.asarray(inst.frame.centre, np.float32))
            if ex.codec.active:
                params_code, held, feature_code, held_feature = self.coded_vectors(
                    iid, inst.params, entry.caption_feature, sent.get(iid), rounds.get(iid), features.get(iid))
                cloud_code = None
                if cloud is not None and ex.codec.cloud_bits < 32:
                    cloud_code = CodedCloud(*encode_cloud(cloud, ex.codec.cloud_bits)[:2], ex.codec.cloud_bits)
                space, form = inst.observed, None
                tracked = inst.observed is not None and ex.codec.delta and ex.codec.leave_out_held
                if tracked:  # the change to the receiver's copy (booked as the whole space on acknowledgement)
                    space, form = observed_change(inst.observed, observed.get(iid))
                    form = None if form == "whole" else form
                payloads.append((InstancePayload(
                    iid, inst.bank, held, *box, inst.frame.half, inst.frame.origin, inst.frame.version, entry.caption,
                    None if feature_code is None else held_feature, entry.confidence, cloud, space, params_code,
                    feature_code, cloud_code, form),
                    held, points, (held_feature, inst.observed.copy() if tracked else None)))
                continue
            dtype = np.float16 if ex.float16 else np.float32
            payloads.append((InstancePayload(
                iid, inst.bank, inst.params.astype(dtype), *box, inst.frame.half,
                inst.frame.origin, inst.frame.version, entry.caption, entry.caption_feature.astype(dtype),
                entry.confidence, cloud, inst.observed), inst.params, points, None))
        if max_bytes is not None and np.isfinite(max_bytes):
            payloads = self._fit(payloads, receiver, round_index, degree, max_bytes)
            if payloads is None:
                return None
        if chosen is not None and not payloads:  # the choice kept nothing (changed-only, capacity): send nothing
            return None
        for payload, params, points, coded in payloads:
            sent[payload.instance_id] = params
            rounds[payload.instance_id] = round_index
            if points is not None:
                clouds[payload.instance_id] = points
            if coded is not None:  # what the receiver holds of the feature and the observed space
                features[payload.instance_id] = coded[0]
                if coded[1] is not None:
                    observed[payload.instance_id] = coded[1]
        self._unacknowledged[receiver] = (sent, clouds, rounds, features, observed)
        return ParameterMessage(self.index, receiver, round_index, [item[0] for item in payloads], degree,
                                ex.codec.lossless)

    def coded_vectors(self, iid: int, params: np.ndarray, feature: np.ndarray, copy: np.ndarray | None,
                      copy_round: int | None, feature_copy: np.ndarray | None
                      ) -> tuple[CodedVector, np.ndarray, CodedVector | None, np.ndarray]:
        """Instance ``iid``'s vector and feature as the codec sends them to a receiver holding ``copy`` (its
        reconstruction, acknowledged at ``copy_round``) and ``feature_copy``: the codes, and what the receiver
        will hold (the same arithmetic at both ends). With deltas the vector goes as its difference to the copy
        (whole the first time); a feature the receiver holds unchanged is left out (None)."""
        c = self.config.exchange.codec
        base = copy if c.delta and copy is not None and copy_round is not None else None
        params_code, held = encode_vector(params, c.bits, c.block, base, copy_round if base is not None else None,
                                          c.keep if base is not None else 1.0)
        feature_code, held_feature = encode_vector(feature, c.feature_bits, c.block)
        if c.delta and c.leave_out_held and feature_copy is not None and np.array_equal(held_feature, feature_copy):
            return params_code, held, None, feature_copy
        return params_code, held, feature_code, held_feature

    def _fit(self, payloads: list, receiver: int, round_index: int, degree: int, max_bytes: float) -> list | None:
        """The payloads that fit in ``max_bytes``: taken in ``instance_priority`` order, each one that still fits
        (first fit: a big network does not block the small ones behind it), kept in message order."""
        def size_of(items: list) -> int:
            kept = [item[0] for item in sorted(items, key=lambda item: item[0].instance_id)]
            return len(to_bytes(ParameterMessage(self.index, receiver, round_index, kept, degree,
                                                 self.config.exchange.codec.lossless)))

        empty = size_of([])
        if empty > max_bytes:
            return None
        order = self.instance_priority(receiver, [item[0].instance_id for item in payloads])
        by_id = {item[0].instance_id: item for item in payloads}
        chosen, used = [], empty
        for iid in order:
            cost = size_of([by_id[iid]]) - empty
            if used + cost <= max_bytes:
                chosen.append(by_id[iid])
                used += cost
        while chosen and size_of(chosen) > max_bytes:  # the header's few bytes of JSON are not quite additive
            chosen.pop()
        keep = {item[0].instance_id for item in chosen}
        return [item for item in payloads if item[0].instance_id in keep]

    def instance_priority(self, receiver: int, ids: Sequence[int]) -> list[int]:
        """``ids`` in the order a full link serves them: those ``receiver`` lacks first, then the oldest copies
        there (the round each last reached it), ties by id; what a full link left out leads the next message."""
        rounds = self.sent_rounds.get(receiver, {})
        return sorted(ids, key=lambda iid: (iid in rounds, rounds.get(iid, -1), iid))

    def shareable_ids(self) -> list[int]:
        """The instances a parameter message carries: its own (with pixels of its own frames), and the
        adopted ones too with ``forward_adopted`` or under DiNNO and DSGD (each agent shares its whole
        model, as they prescribe: an adopted copy that never travels back is an edge with one end)."""
        forward = self.config.exchange.forward_adopted or self.config.consistency.algorithm in ("dinno", "dsgd")
        return [iid for iid in self.mapper.live_ids() if forward or self.mapper.keyframes.has_pixels(iid)]

    def acknowledge(self, receiver: int, kind: str, delivered: bool, round_index: int) -> None:
        """The link told the sender whether its ``kind`` message reached ``receiver`` (an
        acknowledgement, not counted in bytes). Only a delivered message changes what this agent
        believes the receiver holds: a lost first message with an instance's cloud is sent again with
        its cloud next time, and changed-only sending compares with what really arrived."""
        if delivered:
            self.delivered_round[kind][receiver] = round_index
        if kind != "params":
            return
        booked = self._unacknowledged.pop(receiver, None)
        if delivered and booked is not None:
            (self.sent_vectors[receiver], self.sent_cloud_points[receiver], self.sent_rounds[receiver],
             self.sent_features[receiver], self.sent_observed[receiver]) = booked

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
