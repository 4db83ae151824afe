"""A recorded episode: the team's calls (``round``, ``snapshots``, ``surface_coverage``, ``column_maps``, ``done``,
``release``) answered from a ``Recording`` in milliseconds, with what the plan changes modelled.

Replayed as recorded (the same whatever is sent): each agent's frames, poses, own instances with their boxes,
confidence, network sizes and observed spaces, the probes and columns each instance alone fills, payload sizes.
Computed from the plan, as ``Team.round`` does: which links are up (range from the recorded positions, capacity
filled in the sender's priority order), every message's bytes, the budget, the success draws (the same seeded
draw per message, in the same order, as ``mapping.team.channel``), what each receiver holds of each sender and
from which round, what each sender knows of it (``LinkState``, ``InstanceOnLink``), the peers' positions.

Modelled (the model, fitted and checked in docs/transfer.md):
- a receiver's map is its own instances plus every copy it adopted, each as the sender's instance was in the
  round of its last copy (its columns, and the share ``copy_share`` of the probes it covers beyond the receiver's
  own: a copy is aligned into another map and pulled by eq. 12, and reproduces less there than where it was
  trained); a copy is adopted or matched as the receiver's alignment decided in the recording for the round it
  first arrived, and a matched copy adds nothing (what parameter consistency, eq. 12, moves between two maps of
  one object is not modelled);
- ray messages move positions (``peer_poses``) and cost bytes; render consistency (eq. 13) adds nothing;
- DSGD's listings, point-cloud messages and forwarding adopted copies are not modelled (refused).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from mapping.model.topdown import ColumnMap
from mapping.team.channel import DELIVERED, DROPPED, OVER_BUDGET
from mapping.team.codec import vector_wire_bytes
from mapping.team.links import LinkLimits, round_limits
from mapping.team.plan import ChannelConfig, RoundPlan
from mapping.team.recording import ADOPT, UNALIGNED, AgentRecording, Recording
from mapping.team.report import (AgentSnapshot, AlignmentCounts, ConsistencyTerms, DeliveryRecord, InstanceOnLink,
                                 LinkState, LossTerms, PeerKnowledge, RoundReport, priority_order)

COPY_SHARE = 1.0
"""Share of the probes an adopted copy covers beyond the receiver's own map that it reproduces there (a fixed
pseudo-random subset of the probes; fitted on validation worlds in docs/recorded.md)."""


@dataclass(frozen=True)
class RecordedFrame:
    """What the observation reads of a frame: its pose, and the points its depth hit (one per map cell)."""

    pose: np.ndarray
    points: np.ndarray

    def backproject(self, stride: int = 1) -> np.ndarray:
        return self.points


class RecordedTeam:
    """A team answered from ``recording`` under ``channel`` (module docstring); ``config`` is the team's
    ``TeamConfig`` (its exchange settings price messages), ``seed`` the episode's (the success draws)."""

    def __init__(self, recording: Recording, config, channel: ChannelConfig = ChannelConfig(), seed: int = 0,
                 copy_share: float = COPY_SHARE):
        ex = config.exchange
        if config.consistency.algorithm in ("dinno", "dsgd") or ex.forward_adopted or ex.point_clouds or config.global_map:
            raise ValueError("a recorded episode models instance maps under parameter consensus only: consistency "
                             f"{config.consistency.algorithm!r}, forward_adopted={ex.forward_adopted}, "
                             f"point_clouds={ex.point_clouds}, global_map={config.global_map} are not modelled; play "
                             "the real episode")
        self.recording, self.config, self.channel_config = recording, config, channel
        self.agents: list[AgentRecording] = recording.agents
        n = len(self.agents)
        if not 0.0 <= copy_share <= 1.0:
            raise ValueError(f"copy_share must be in [0, 1], got {copy_share}")
        self.num_agents, self.seed, self.share = n, int(seed), float(copy_share)
        self.success = np.broadcast_to(np.asarray(channel.success_matrix(n), float), (n, n))
        self.budget = channel.budget_bytes
        self.rng = np.random.default_rng(zlib.crc32(f"channel-{seed}".encode()))
        self.bytes_sent, self.bytes_received = np.zeros(n, np.int64), np.zeros(n, np.int64)
        self.link_bytes = np.zeros((n, n), np.int64)
        self.round_index = 0
        self.held = [{j: {} for j in range(n) if j != i} for i in range(n)]  # receiver -> sender -> id -> round
        self.decision = [{j: {} for j in range(n) if j != i} for i in range(n)]  # receiver -> sender -> id -> own/ADOPT
        self.cloud_sent = [{j: {} for j in range(n) if j != i} for i in range(n)]  # sender -> receiver -> id -> points
        self.delivered_round = [{"params": {}, "rays": {}} for _ in range(n)]
        self.peer_positions = [{} for _ in range(n)]
        self.params_round = [{} for _ in range(n)]  # receiver -> sender -> round its last parameters arrived
        self.last_links_up: np.ndarray | None = None
        self.index = [{int(iid): m for m, iid in enumerate(a.ids)} for a in self.agents]
        self.born = [self._born(a) for a in self.agents]
        self._new_frames: list[tuple] = [()] * n
        probes = self.agents[0].probes
        self.lucky = (np.random.default_rng(7).random(probes) < self.share) if probes else np.zeros(0, bool)

    @staticmethod
    def _born(a: AgentRecording) -> dict[int, int]:
        """Own id -> the first snapshot's round count that showed it shareable (``TeamMember.born_round``)."""
        seen = a.shareable
        return {int(iid): int(np.argmax(seen[:, m])) + 1 for m, iid in enumerate(a.ids) if seen[:, m].any()}

    # ---- the team's calls ------------------------------------------------------------------------
    @property
    def done(self) -> bool:
        return self.round_index >= self.recording.rounds

    def rounds_total(self) -> int:
        return self.recording.rounds

    def _t(self, rounds: int) -> int:
        """The recorded round whose state holds after ``rounds`` rounds (-1: none yet)."""
        return min(rounds, self.recording.rounds) - 1

    def round(self, plan: RoundPlan) -> RoundReport:
        n = self.num_agents
        plan = plan.validate(n)
        t = self.round_index
        rt = min(t, self.recording.rounds - 1)
        limits = self._limits(rt)
        sent0, recv0, link0 = self.bytes_sent.copy(), self.bytes_received.copy(), self.link_bytes.copy()
        deliveries, counts = [], {f"agent_{i}": AlignmentCounts() for i in range(n)}
        room = limits.room_bytes.copy()
        for i in range(n):
            for j in range(n):
                if not limits.up[i, j]:
                    continue
                if plan.send_params[i, j]:
                    only = None if plan.send_instances is None else plan.send_instances.get((i, j), ())
                    new = plan.send_new is not None and bool(plan.send_new[i, j])
                    message = self._parameter_message(i, j, rt, only, new, room[i, j])
                    if message is not None:
                        size, ids = message
                        status = self._transmit(i, j, size)
                        room[i, j] -= size if status != OVER_BUDGET else 0
                        deliveries.append(DeliveryRecord(i, j, "params", status, size if status != OVER_BUDGET else 0))
                        if status == DELIVERED:
                            self._deliver_params(i, j, rt, t, ids, counts[f"agent_{j}"])
                if plan.share_rays[i, j] and self.agents[i].ray_bytes[rt] > 0:
                    ray_seed = zlib.crc32(f"rays-{self.seed}-{t}-{i}-{j}".encode())  # Team.round's
                    size = int(self.agents[i].ray_bytes[rt]) + len(str(ray_seed)) - 1  # recorded with seed 0
                    if size <= room[i, j]:
                        status = self._transmit(i, j, size)
                        room[i, j] -= size if status != OVER_BUDGET else 0
                        deliveries.append(DeliveryRecord(i, j, "rays", status, size if status != OVER_BUDGET else 0))
                        if status == DELIVERED:
                            self.delivered_round[i]["rays"][j] = t
                            self.peer_positions[j][i] = (t, self._ray_position(i, rt, ray_seed))
        self.round_index += 1
        self.last_links_up = limits.up.copy()
        self._new_frames = [self._frames(a, rt) if t < a.rounds else () for a in self.agents]
        snapshots = self.snapshots()
        sent, received = self.bytes_sent - sent0, self.bytes_received - recv0
        statuses = [d.status for d in deliveries]
        for snap in snapshots:
            mine = [d.status for d in deliveries if d.sender == snap.index]
            snap.messages.update({status: mine.count(status) for status in snap.messages})
            snap.bytes_sent, snap.bytes_received = int(sent[snap.index]), int(received[snap.index])
        zero = [0.0] * n
        return RoundReport(
            round=t, frames_read=[int(np.diff(a.frame_offsets)[rt]) if t < a.rounds else 0 for a in self.agents],
            keyframes=[0] * n, bytes_per_link=self.link_bytes - link0, bytes_sent=sent.tolist(),
            bytes_received=received.tolist(), delivered=statuses.count(DELIVERED), dropped=statuses.count(DROPPED),
            over_budget=statuses.count(OVER_BUDGET), deliveries=deliveries, alignment=counts,
            losses={f"agent_{i}": LossTerms(0.0, 0.0, ConsistencyTerms()) for i in range(n)}, local_s=zero,
            consistency_s=list(zero), exchange_s=0.0, done=self.done, agents=snapshots, links=limits)

    def snapshots(self) -> list[AgentSnapshot]:
        rt = self._t(self.round_index)
        snaps = [self._snapshot(i, rt) for i in range(self.num_agents)]
        if self.last_links_up is not None:
            for snap in snaps:
                snap.links_up = {j: bool(self.last_links_up[snap.index, j]) for j in range(self.num_agents) if j != snap.index}
        return snaps

    def surface_coverage(self, points: np.ndarray, normals: np.ndarray) -> list[np.ndarray]:
        """Per agent, the probes its own instances and its adopted copies reproduce (the recording's probes:
        ``points`` must be the ones it was made with)."""
        if len(points) != self.agents[0].probes:
            raise ValueError(f"this recording holds {self.agents[0].probes} probes, asked for {len(points)}")
        rt = self._t(self.round_index)
        return [self._coverage(i, rt) for i in range(self.num_agents)]

    def column_maps(self, grid) -> list[ColumnMap | None]:
        rt = self._t(self.round_index)
        return [self._columns(i, rt) for i in range(self.num_agents)]

    def release(self) -> None:
        """Nothing to free (no threads, no processes)."""

    def close(self) -> None:
        """Nothing to stop."""

    # ---- the channel --------------------------------------------------------------------------------
    def _limits(self, rt: int) -> LinkLimits:
        cfg = self.channel_config
        if cfg.link_range_m is None and cfg.link_mb_per_round is None:
            return LinkLimits.unlimited(self.num_agents)
        positions = np.stack([a.positions[min(rt, a.rounds - 1)] for a in self.agents])
        return round_limits(np.nan_to_num(positions), cfg.link_range_m, cfg.link_capacity_bytes)

    def _transmit(self, i: int, j: int, size: int) -> str:
        """``Channel.transmit_bytes`` on a size: over budget costs nothing; else charged, then one draw."""
        if self.budget is not None and size > max(0.0, self.budget - float(self.bytes_sent[i])):
            return OVER_BUDGET
        self.bytes_sent[i] += size
        self.link_bytes[i, j] += size
        if self.rng.random() >= self.success[i, j]:
            return DROPPED
        self.bytes_received[j] += size
        return DELIVERED

    def _parameter_message(self, i: int, j: int, rt: int, only, new: bool, room: float) -> tuple[int, list[int]] | None:
        """(bytes, instance ids) of i's parameter message to j, as ``Outbox.parameter_message`` builds it."""
        a, ex, index = self.agents[i], self.config.exchange, self.index[i]
        copies, clouds = self.held[j][i], self.cloud_sent[i][j]
        chosen = None if only is None else {int(v) for v in only}
        shareable = [int(iid) for m, iid in enumerate(a.ids) if a.shareable[rt, m]]
        ids = [iid for iid in shareable if chosen is None or iid in chosen or (new and self.born[i][iid] == rt + 1)]
        if chosen is not None and not ids:
            return None
        sizes = {}
        for iid in ids:
            m = index[iid]
            if ex.changed_only is not None and iid in copies and iid in clouds and \
                    self._change(i, m, copies[iid], rt) <= ex.changed_only:
                continue
            cloud = iid not in clouds or a.cloud_points[rt, m] >= ex.resend_cloud_growth * clouds[iid]
            sizes[iid] = int(a.payload_first[rt, m] if cloud or iid not in copies else a.payload_repeat[rt, m])
        header = int(a.header_bytes[rt])
        if np.isfinite(room):
            if header > room:
                return None
            used, kept = header, []
            for iid in sorted(sizes, key=lambda k: (k in copies, copies.get(k, -1), k)):
                if used + sizes[iid] <= room:
                    kept.append(iid)
                    used += sizes[iid]
            sizes = {iid: sizes[iid] for iid in kept}
        if chosen is not None and not sizes:
            return None
        return header + sum(sizes.values()), sorted(sizes)

    def _deliver_params(self, i: int, j: int, rt: int, t: int, ids: list[int], counts: AlignmentCounts) -> None:
        a = self.agents[i]
        table = self.agents[j].matches.get(i)
        column = {int(pid): k for k, pid in enumerate(table[0])} if table is not None else {}
        for iid in ids:
            if iid not in self.decision[j][i]:
                k = column.get(iid)
                decided = int(table[1 + rt, k]) if k is not None else UNALIGNED
                self.decision[j][i][iid] = decided
                if decided == ADOPT:
                    counts.adopted += 1
                elif decided >= 0:
                    counts.matched += 1
            self.held[j][i][iid] = rt
            self.cloud_sent[i][j][iid] = int(a.cloud_points[rt, self.index[i][iid]]) if \
                iid not in self.cloud_sent[i][j] or a.cloud_points[rt, self.index[i][iid]] >= \
                self.config.exchange.resend_cloud_growth * self.cloud_sent[i][j][iid] else self.cloud_sent[i][j][iid]
        self.delivered_round[i]["params"][j] = t
        self.params_round[j][i] = t

    def _ray_position(self, i: int, rt: int, seed: int) -> np.ndarray:
        """Where agent i's ray message of round ``rt`` says it was: the last of the poses ``Outbox.ray_message``
        draws with ``seed`` from the frames it had read."""
        a, c = self.agents[i], self.config.consistency
        stop = int(a.frames_read[rt])
        first = max(0, stop - self.config.frames_per_round)
        if c.ray_poses == "mapped" and first > 0:
            picks = np.unique(np.random.default_rng([seed, 7]).choice(first, size=min(c.poses_per_message, first),
                                                                       replace=False))
        else:
            picks = np.unique(np.linspace(first, stop - 1, c.poses_per_message).round().astype(int))
        return a.frame_poses[int(picks[-1]), :3, 3].astype(np.float64)

    # ---- what each agent holds and knows ---------------------------------------------------------------
    def _change(self, i: int, m: int, copy_round: int, rt: int) -> float:
        value = float(self.agents[i].change[m, copy_round, rt])
        return 1.0 if not np.isfinite(value) else min(1.0, value)

    def _frames(self, a: AgentRecording, rt: int) -> tuple[RecordedFrame, ...]:
        poses = a.frame_poses[a.frame_offsets[rt]:a.frame_offsets[rt + 1]]
        points = a.observed_points[a.observed_offsets[rt]:a.observed_offsets[rt + 1]].astype(np.float64)
        return tuple(RecordedFrame(p.astype(np.float64), points if k == 0 else np.zeros((0, 3)))
                     for k, p in enumerate(poses))

    def _adopted(self, i: int) -> list[tuple[int, int, int]]:
        """(sender, sender's instance index, copy round) of every copy agent i adopted."""
        return [(j, self.index[j][iid], c) for j, table in self.held[i].items() for iid, c in table.items()
                if self.decision[i][j].get(iid) == ADOPT]

    def _coverage(self, i: int, rt: int) -> np.ndarray:
        a = self.agents[i]
        covered = np.zeros(a.probes, bool)
        if rt < 0:
            return covered
        r = min(rt, a.rounds - 1)
        for m in np.flatnonzero(a.live[r]):
            covered |= a.covered(r, m)
        copies = np.zeros(a.probes, bool)
        for j, m, c in self._adopted(i):
            copies |= self.agents[j].covered(c, m)
        return covered | (copies & self.lucky)

    def _columns(self, i: int, rt: int) -> ColumnMap | None:
        if rt < 0:
            return None
        a = self.agents[i]
        r = min(rt, a.rounds - 1)
        top, decided = a.top[r].astype(np.float64), a.decided[r].astype(np.float64)
        flat_top, flat_decided = top.reshape(-1), decided.reshape(-1)
        for j, m, c in self._adopted(i):
            cols, ctop, cdec = self.agents[j].columns(c, m)
            flat_top[cols] = np.fmax(flat_top[cols], ctop)
            flat_decided[cols] = np.minimum(1.0, flat_decided[cols] + cdec)
        return ColumnMap(top, decided)

    def _snapshot(self, i: int, rt: int) -> AgentSnapshot:
        a, n, ex = self.agents[i], self.num_agents, self.config.exchange
        budget_left = float("inf") if self.budget is None else max(0.0, self.budget - float(self.bytes_sent[i]))
        if rt < 0:  # before the first round: nothing held, nothing sent (``TeamMember.snapshot`` on an empty map)
            return AgentSnapshot(i, 0, 0, (), None, 0, 0, {}, budget_left, 0, frames_total=a.frames_total,
                                 links={j: LinkState(0.0, 0.0, 0.0, None, None, 0) for j in range(n) if j != i},
                                 instance_links={j: () for j in range(n) if j != i})
        r = min(rt, a.rounds - 1)
        alive = int(a.live[r].sum())
        live = [int(iid) for m, iid in enumerate(a.ids) if a.shareable[r, m]]  # what its messages and links carry
        peers = {}
        for j, table in self.held[i].items():
            b = self.agents[j]
            boxes = tuple((b.lo[c, self.index[j][iid]], b.hi[c, self.index[j][iid]]) for iid, c in table.items()
                          if b.is_object[self.index[j][iid]])
            if j in self.params_round[i] or j in self.peer_positions[i]:  # an empty message counts too
                peers[j] = PeerKnowledge(len(table), boxes, self.params_round[i].get(j), self.peer_positions[i].get(j))
        links, per_instance = {}, {}
        tolerance = ex.up_to_date_tolerance
        for j in (k for k in range(n) if k != i):
            copies = self.held[j][i]
            changes = [self._change(i, self.index[i][iid], copies[iid], r) if iid in copies else 1.0 for iid in live]
            count = max(len(changes), 1)
            links[j] = LinkState(holds=sum(iid in copies for iid in live) / count,
                                 up_to_date=sum(c <= tolerance for c in changes) / count if changes else 0.0,
                                 change=float(np.mean(changes)) if changes else 0.0,
                                 params_round=self.delivered_round[i]["params"].get(j),
                                 rays_round=self.delivered_round[i]["rays"].get(j), bytes_sent=int(self.link_bytes[i, j]))
            shared = {own for own in self.decision[i][j].values() if own >= 0}
            items = []
            for iid, change in zip(live, changes):
                m = self.index[i][iid]
                items.append(InstanceOnLink(
                    iid, iid not in copies, change, copies.get(iid), iid in shared, float(a.confidence[r, m]),
                    float(np.linalg.norm(a.hi[r, m] - a.lo[r, m])), self.born[i][iid],
                    vector_wire_bytes(ex, int(a.nparams[r, m]), iid in copies)))
            per_instance[j] = tuple(priority_order(items))
        adopted = len(self._adopted(i))
        position = a.positions[r]
        return AgentSnapshot(
            i, self.round_index, int(a.frames_read[r]), self._new_frames[i],
            None if not np.all(np.isfinite(position)) else position.astype(np.float64), alive + adopted, len(live),
            peers, budget_left, int(self.link_bytes[i].sum()), links=links, frames_total=a.frames_total,
            instance_links=per_instance,
            map_bytes=sum(vector_wire_bytes(ex, int(a.nparams[r, self.index[i][iid]]), False) for iid in live))


__all__ = ["COPY_SHARE", "RecordedFrame", "RecordedTeam"]
