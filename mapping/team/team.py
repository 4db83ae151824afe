"""A team of mapping agents advancing in rounds: ``Team.round(plan) -> RoundReport``.

One round (DESIGN.md, "the flow of one env step"): every agent reads its next frames, fuses them and
runs its local iterations (the data loss, and eq. 12 toward what it last received when
``ConsistencyConfig.local_consensus``); the channel carries the messages the plan asks for; every receiver holds
and aligns what arrived (with DSGD, each pair of agents then swaps its pairs and degrees, so both ends of an
edge use one Metropolis weight) and runs its consistency iterations (eq. 12-13). The plan is two (N, N)
boolean matrices, ``send_params[i, j]`` (i sends its parameters to j) and ``share_rays[i, j]`` (i
shares rays of views it has mapped with j), diagonal False: the env's actions and the CLI's scripted policies
both drive the team through it only.

Time: each agent's own compute seconds are reported (a fleet gives each robot its own computer), and
``fleet_s`` = max over agents of the local phase + the exchange + max over agents of the consistency
phase: the wall clock such a fleet would see.
"""

from __future__ import annotations

import time
import zlib
from pathlib import Path
from typing import Sequence

import numpy as np

from mapping.model.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from mapping.model.fleet import ExtraLoss, fleet_train
from mapping.perception.vocabulary import Vocabulary
from mapping.team.channel import DELIVERED, DROPPED, OVER_BUDGET, Channel
from mapping.team.config import TeamConfig
from mapping.team.plan import ChannelConfig, PlanError, RoundPlan
from mapping.team.links import LinkLimits, round_limits
from mapping.team.member import AgentStream, TeamMember
from mapping.team.message_checks import team_rules
from mapping.team.messages import DegreeMessage, ParameterMessage, RayMessage, to_bytes
from mapping.team.report import (AgentSnapshot, AlignmentCounts, ConsistencyTerms, DeliveryRecord, LossTerms,
                                 RoundReport)
from mapping.team.state import member_state, restore_member


LEARNERS = ("per_agent", "fleet")
"""How a team's members train: each on its own, or batched together (``mapping.model.fleet``)."""


class Team:
    """N agents over N streams, one channel between them.

    Args:
        streams: one ``AgentStream`` per agent.
        config: the learning settings (same for every agent).
        vocabulary: category names for zero-shot labels (which instances are walls, floor, ceiling).
        seed: drives network initialisation, ray sampling, ray-message seeds and channel draws.
        channel: link success and budget.
        device: "cpu", "cuda" or "auto".
        workers: threads that run the agents' local and consistency phases side by side (1: in turn).
            Each agent touches only its own state there (streams are read in the calling thread
            first), so results do not depend on it; give each torch 1 intra-op thread when > 1.
        processes: None (every member in this process) or ``"ray"``: each member in a Ray actor of its own
            (``mapping.team.remote``; one process per agent, on this machine or a cluster), exchanging only
            serialised messages; the streams stay here. The members are then called side by side.
        learner: ``"per_agent"`` (each member trains on its own, on the worker threads) or ``"fleet"``
            (``mapping.model.fleet``: every member's local and consistency iterations batched into one
            computation per step, in the calling thread on its torch threads; the same maps to float
            tolerance; members in this process only). A fleet member's compute seconds count a share
            of the joint steps in proportion to its iterations.
    """

    def __init__(self, streams: Sequence[AgentStream], config: TeamConfig, vocabulary: Vocabulary, seed: int = 0,
                 channel: ChannelConfig = ChannelConfig(), device: str = "auto", workers: int = 1,
                 processes: str | None = None, learner: str = "per_agent"):
        if not streams:
            raise ValueError("a team needs at least one agent stream")
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        if processes not in (None, "ray"):
            raise ValueError(f"processes must be None (members in this process) or 'ray', got {processes!r}")
        if learner not in LEARNERS:
            raise ValueError(f"learner must be one of {LEARNERS}, got {learner!r}")
        if learner == "fleet" and processes:
            raise ValueError("learner='fleet' batches members in this process: it cannot train members in "
                             f"processes={processes!r}")
        self.processes, self.learner = processes, learner
        self.workers = len(streams) if processes else min(workers, len(streams))
        self._pool = None
        self.config, self.seed = config, seed
        # a global map: every agent's network starts as agent 0's (MACIM deep-copies robot 0's map)
        init_seed = seed * 100 if config.global_map and config.shared_global_init else None
        if processes == "ray":
            from mapping.team.remote import RemoteMember, start_member_processes  # noqa: PLC0415

            placement = start_member_processes(len(streams), device)
            self.members = [RemoteMember(i, s, config, vocabulary, seed=seed * 100 + i, placement=placement,
                                         init_seed=init_seed) for i, s in enumerate(streams)]
        else:
            self.members = [TeamMember(i, s, config, vocabulary, seed=seed * 100 + i, device=device, init_seed=init_seed)
                            for i, s in enumerate(streams)]
        self.channel_config = channel
        rules = team_rules(config.mapping, config.exchange, vocabulary.features.shape[1])
        self.channel = Channel(len(streams), channel.success_matrix(len(streams)), channel.budget_bytes,
                               seed=zlib.crc32(f"channel-{seed}".encode()), rules=rules)
        self.round_index = 0
        self.positions = np.zeros((len(streams), 3))  # each agent's camera after its last frame read
        self.last_links_up: np.ndarray | None = None  # (N, N) the links of the last round

    @property
    def num_agents(self) -> int:
        return len(self.members)

    @property
    def done(self) -> bool:
        """Every agent has read all its frames."""
        return all(m.done for m in self.members)

    def rounds_total(self) -> int:
        """Rounds until every stream ends."""
        f = self.config.frames_per_round
        return max(-(-len(m.stream) // f) for m in self.members)

    def round(self, plan: RoundPlan) -> RoundReport:
        """Advance every agent by one round under ``plan`` (see the module docstring)."""
        n = self.num_agents
        plan = plan.validate(n)
        t = self.round_index
        reads = [m.read_round() for m in self.members]  # the streams stay on this thread (GL, encoders)
        if self.learner == "fleet":
            works = self.each_member(lambda m: m.prepare_local(reads[m.index]))
            trained, shared_s = self.fleet_train([w.iterations for w in works], [w.extra for w in works])
            local = [m.finish_local(w, loss, s) for m, w, loss, s in zip(self.members, works, trained, shared_s)]
        else:
            local = self.each_member(lambda m: m.local_round(reads[m.index]))
        # ---- exchange -------------------------------------------------------------------------
        start = time.perf_counter()
        sent0, recv0, link0 = self.channel.bytes_sent.copy(), self.channel.bytes_received.copy(), \
            self.channel.link_bytes.copy()
        limits = self.link_limits(reads)
        degree = (plan.send_params & limits.up).sum(axis=1)
        params_in: dict[int, list[ParameterMessage]] = {j: [] for j in range(n)}
        rays_in: dict[int, list[RayMessage]] = {j: [] for j in range(n)}
        deliveries = []
        room = limits.room_bytes.copy()
        for i in range(n):
            for j in range(n):
                if not limits.up[i, j]:
                    continue
                messages = []
                if plan.send_params[i, j] and self.config.exchange.point_clouds:
                    messages.append(self.members[i].point_cloud_message(j, t))
                elif plan.send_params[i, j]:
                    only = None if plan.send_instances is None else plan.send_instances.get((i, j), ())
                    new = plan.send_new is not None and bool(plan.send_new[i, j])
                    messages.append(self.members[i].parameter_message(
                        j, t, int(degree[i]), only, None if np.isinf(room[i, j]) else float(room[i, j]), new))
                if plan.share_rays[i, j]:
                    messages.append(self.members[i].ray_message(j, t, zlib.crc32(f"rays-{self.seed}-{t}-{i}-{j}".encode())))
                accept = self.members[j].arrival_problem if self.config.exchange.codec.active else None
                for message in messages:
                    if message is None:
                        continue
                    if np.isfinite(room[i, j]):  # a capacity: what does not fit is not sent (rays after parameters)
                        data = to_bytes(message)
                        if len(data) > room[i, j]:
                            continue
                        d = self.channel.transmit_bytes(message.sender, message.receiver, message.kind, data, accept)
                        room[i, j] -= d.bytes
                    else:
                        d = self.channel.transmit(message, accept)
                    self.members[i].acknowledge(j, d.kind, d.status == DELIVERED, t)
                    deliveries.append(DeliveryRecord(i, j, d.kind, d.status, d.bytes))
                    if d.status == DELIVERED and d.kind != "points":  # clouds are counted, not learned from
                        (params_in if d.kind == "params" else rays_in)[j].append(d.message)
                        if d.kind != "params":
                            self.members[j].note_rays(d.message)
        exchange_s = time.perf_counter() - start

        # ---- arrival, each receiver on its own --------------------------------------------------------
        def receive(member: TeamMember) -> tuple[AlignmentCounts, float]:
            t0 = time.perf_counter()
            counts = AlignmentCounts()
            for message in params_in[member.index]:
                counts.add(member.receive_parameters(message))
            return counts, time.perf_counter() - t0

        # ---- DSGD only: each end tells the other its pairs and degrees (same weight at both ends) ----
        listings_in: dict[int, list[DegreeMessage]] = {j: [] for j in range(n)}
        acknowledged: dict[int, set[int]] = {i: set() for i in range(n)}

        def swap_listings() -> None:
            for member in self.members:
                for message in member.degree_messages(t):
                    if not limits.up[message.sender, message.receiver]:
                        continue
                    d = self.channel.transmit(message)
                    deliveries.append(DeliveryRecord(message.sender, message.receiver, d.kind, d.status, d.bytes))
                    if d.status == DELIVERED:
                        listings_in[message.receiver].append(d.message)
                        acknowledged[message.sender].add(message.receiver)

        # ---- consistency, each receiver on its own ----------------------------------------------------
        def agree(member: TeamMember) -> ConsistencyTerms:
            k = member.index
            if self.learner == "fleet":  # prepared here, trained below with the other members
                return member.prepare_consistency(rays_in[k], t, listings_in[k], frozenset(acknowledged[k]))
            return member.consistency_round(rays_in[k], t, listings_in[k], frozenset(acknowledged[k]))

        if self.config.consistency.algorithm == "dsgd":  # the listings cross between arrival and mixing
            arrivals = self.each_member(receive)
            swap_listings()
            agreed = self.each_member(agree)
        else:  # arrival and consistency in one pass per member: the order every other figure was made in
            both = self.each_member(lambda m: (receive(m), agree(m)))
            arrivals, agreed = [b[0] for b in both], [b[1] for b in both]
        if self.learner == "fleet":
            trained, shared_s = self.fleet_train([w.iterations for w in agreed], [w.extra for w in agreed])
            agreed = [m.finish_consistency(w, loss, s)
                      for m, w, loss, s in zip(self.members, agreed, trained, shared_s)]
        alignment, losses, consistency_s = {}, {}, []
        for member, (counts, arrival_s), terms in zip(self.members, arrivals, agreed):
            alignment[member.name] = counts
            losses[member.name] = LossTerms(local[member.index].loss, local[member.index].parameter, terms)
            consistency_s.append(arrival_s + terms.seconds)
        self.round_index += 1
        statuses = [d.status for d in deliveries]
        sent, received = self.channel.bytes_sent - sent0, self.channel.bytes_received - recv0
        self.last_links_up = limits.up.copy()
        snapshots = self.snapshots([[f for f, _ in read[0]] for read in reads])
        for snap in snapshots:
            mine = [d.status for d in deliveries if d.sender == snap.index]
            snap.messages.update({status: mine.count(status) for status in snap.messages})
            snap.bytes_sent, snap.bytes_received = int(sent[snap.index]), int(received[snap.index])
        return RoundReport(
            round=t, frames_read=[len(r.frames) for r in local], keyframes=[r.keyframes for r in local],
            bytes_per_link=self.channel.link_bytes - link0, bytes_sent=sent.tolist(), bytes_received=received.tolist(),
            delivered=statuses.count(DELIVERED), dropped=statuses.count(DROPPED),
            over_budget=statuses.count(OVER_BUDGET), deliveries=deliveries, alignment=alignment, losses=losses,
            local_s=[r.seconds for r in local], consistency_s=consistency_s, exchange_s=max(exchange_s, 0.0),
            done=self.done, agents=snapshots, links=limits)

    def link_limits(self, reads) -> LinkLimits:
        """This round's links from each agent's position after its round's frames (its last one when it read
        none) and ``ChannelConfig``'s range and capacity."""
        cfg = self.channel_config
        if cfg.link_range_m is None and cfg.link_mb_per_round is None:
            return LinkLimits.unlimited(self.num_agents)
        for index, read in enumerate(reads):
            if read[0]:
                self.positions[index] = read[0][-1][0].pose[:3, 3]
        return round_limits(self.positions, cfg.link_range_m, cfg.link_capacity_bytes)

    def fleet_train(self, iterations: list[int], extras: list[ExtraLoss]) -> tuple[list[float], list[float]]:
        """Every member's iterations batched (``mapping.model.fleet.fleet_train``) in the calling thread, on the
        caller's torch threads; each member's last loss, and its share of the seconds (by its iterations)."""
        start = time.perf_counter()
        losses = fleet_train([m.mapper for m in self.members], iterations, extras)
        seconds = time.perf_counter() - start
        total = sum(iterations)
        return losses, [seconds * n / total if total else 0.0 for n in iterations]

    def snapshots(self, new_frames: Sequence[Sequence] | None = None) -> list[AgentSnapshot]:
        """Each agent's own knowledge now (``new_frames[i]``: the frames agent i read in the last round;
        none when not given, e.g. before the first round)."""
        snapshots = [m.snapshot(self.round_index, new_frames[m.index] if new_frames is not None else (),
                                self.channel.budget_left(m.index), self.channel.link_bytes[m.index])
                     for m in self.members]
        if self.last_links_up is not None:  # the radio's view of the last round (every link before the first)
            for snap in snapshots:
                snap.links_up = {j: bool(self.last_links_up[snap.index, j])
                                 for j in range(self.num_agents) if j != snap.index}
        return snapshots

    def surface_coverage(self, points: np.ndarray, normals: np.ndarray) -> list[np.ndarray]:
        """Per agent, which surface samples its map reproduces (``mapping.evaluate.probe``): the reward's and
        the evaluation's view of a map, never an agent's observation. Runs on the worker threads."""
        return self.each_member(lambda m: m.surface_coverage(points, normals))

    def column_maps(self, grid) -> list:
        """Per agent, its own map read on the columns of ``grid`` (``mapping.model.topdown.column_map``): what an
        agent's observation may show of its map. Runs on the worker threads."""
        return self.each_member(lambda m: m.column_map(grid))

    def local_members(self) -> list[TeamMember]:
        """Every member as a ``TeamMember`` in this process (members in processes are copied here): what
        meshing and scoring after a run read."""
        return [m.copy() if self.processes else m for m in self.members]

    def each_member(self, job):
        """``job(member)`` for every member, results in member order; side by side on ``workers``
        threads (``job`` must touch only that member's state, e.g. probing its map)."""
        if self.workers == 1:
            return [job(m) for m in self.members]
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor  # noqa: PLC0415

            self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix="team-agent")
        return list(self._pool.map(job, self.members))

    def close(self) -> None:
        """Stop the worker threads (a team is usable again afterwards: they restart on demand)."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def release(self) -> None:
        """End the member processes (``processes="ray"``) and the worker threads; the team is unusable after."""
        self.close()
        if self.processes:
            for member in self.members:
                member.close()

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_pool"] = None
        return state

    # ---- checkpoints ------------------------------------------------------------------------------
    def save(self, path: str | Path, extra: dict | None = None) -> Path:
        """The whole team after the last round (maps, keyframes, fusion, what each holds of its peers,
        the channel's counters and draws), written atomically; ``extra`` is stored beside it."""
        return save_checkpoint(path, {"round": self.round_index, "seed": self.seed, "positions": self.positions.tolist(),
                                      "links_up": None if self.last_links_up is None else self.last_links_up.tolist(),
                                      "channel": self.channel.state(), "extra": extra or {},
                                      "members": [m.state() if self.processes else member_state(m)
                                                  for m in self.members]})

    def load(self, path: str | Path) -> dict:
        """Restore a team saved by ``save`` (same streams and config); returns its ``extra``."""
        data = load_checkpoint(path)
        if len(data["members"]) != self.num_agents or data["seed"] != self.seed:
            raise CheckpointError(f"{path}: a team of {len(data['members'])} agents with seed {data['seed']}, "
                                  f"not {self.num_agents} with seed {self.seed}")
        for member, state in zip(self.members, data["members"]):
            if self.processes:
                member.restore(state)
            else:
                restore_member(member, state)
        self.channel.restore(data["channel"])
        self.round_index = data["round"]
        self.positions = np.asarray(data.get("positions", self.positions), np.float64).reshape(self.num_agents, 3)
        links = data.get("links_up")
        self.last_links_up = None if links is None else np.asarray(links, bool).reshape(self.num_agents, self.num_agents)
        return data["extra"]


__all__ = ["LEARNERS", "ChannelConfig", "PlanError", "RoundPlan", "RoundReport", "Team"]
