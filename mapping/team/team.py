"""A team of mapping agents advancing in rounds: ``Team.round(plan) -> RoundReport``.

One round (DESIGN.md, "the flow of one env step"): every agent reads its next frames, fuses them and
runs its local iterations (the data loss, and eq. 12 toward what it last received when
``ConsistencyConfig.local_consensus``); the channel carries the messages the plan asks for; every receiver holds
and aligns what arrived and runs its consistency iterations (eq. 12-13). The plan is two (N, N)
boolean matrices, ``send_params[i, j]`` (i sends its parameters to j) and ``share_rays[i, j]`` (i
shares its current rays with j), diagonal False: the env's actions and the CLI's scripted policies
both drive the team through it only.

Time: each agent's own compute seconds are reported (a fleet gives each robot its own computer), and
``fleet_s`` = max over agents of the local phase + the exchange + max over agents of the consistency
phase: the wall clock such a fleet would see.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from mapping.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from mapping.team.channel import DELIVERED, DROPPED, OVER_BUDGET, Channel
from mapping.team.member import AgentStream, TeamConfig, TeamMember, Vocabulary
from mapping.team.messages import ParameterMessage, RayMessage
from mapping.team.state import member_state, restore_member


class PlanError(ValueError):
    """A round plan of the wrong shape, type or with self-links."""


@dataclass
class RoundPlan:
    """Who sends what to whom this round: two (N, N) bool matrices, diagonal False."""

    send_params: np.ndarray
    share_rays: np.ndarray

    @staticmethod
    def always(n: int) -> "RoundPlan":
        full = ~np.eye(n, dtype=bool)
        return RoundPlan(full.copy(), full.copy())

    @staticmethod
    def never(n: int) -> "RoundPlan":
        return RoundPlan(np.zeros((n, n), bool), np.zeros((n, n), bool))

    def validate(self, n: int) -> "RoundPlan":
        """Checked copies as bool arrays (PlanError naming what is wrong)."""
        out = []
        for name in ("send_params", "share_rays"):
            m = np.asarray(getattr(self, name))
            if m.shape != (n, n):
                raise PlanError(f"plan.{name} must be ({n}, {n}) for {n} agents, got shape {m.shape}")
            if m.dtype != bool:
                if not np.all(np.isin(m, (0, 1))):
                    raise PlanError(f"plan.{name} must hold booleans (or 0/1), got values {np.unique(m)[:5]}")
                m = m.astype(bool)
            if np.any(np.diag(m)):
                raise PlanError(f"plan.{name} has self-links (diagonal entries {np.flatnonzero(np.diag(m)).tolist()})")
            out.append(m.copy())
        return RoundPlan(*out)


@dataclass
class RoundReport:
    """What one round did. Per-agent lists are indexed by agent; losses by agent name."""

    round: int
    frames_read: list[int]
    keyframes: list[int]
    bytes_per_link: np.ndarray  # (N, N) bytes sent i -> j this round
    bytes_sent: list[int]
    bytes_received: list[int]
    delivered: int
    dropped: int
    over_budget: int
    deliveries: list[dict]
    alignment: dict[str, dict]
    losses: dict[str, dict]
    local_s: list[float]
    consistency_s: list[float]
    exchange_s: float
    done: bool

    @property
    def compute_s(self) -> list[float]:
        """Each agent's own compute seconds this round."""
        return [a + b for a, b in zip(self.local_s, self.consistency_s)]

    @property
    def fleet_s(self) -> float:
        """Wall clock of a fleet with one computer per robot: slowest local phase + exchange + slowest
        consistency phase."""
        return max(self.local_s, default=0.0) + self.exchange_s + max(self.consistency_s, default=0.0)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["bytes_per_link"] = self.bytes_per_link.tolist()
        d["compute_s"], d["fleet_s"] = self.compute_s, self.fleet_s
        return d


@dataclass(frozen=True)
class ChannelConfig:
    """The links: success probability per message and an optional byte budget per agent."""

    success_probability: float = 1.0
    budget_bytes: float | None = None


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
    """

    def __init__(self, streams: Sequence[AgentStream], config: TeamConfig, vocabulary: Vocabulary, seed: int = 0,
                 channel: ChannelConfig = ChannelConfig(), device: str = "auto", workers: int = 1):
        if not streams:
            raise ValueError("a team needs at least one agent stream")
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.workers = min(workers, len(streams))
        self._pool = None
        self.config, self.seed = config, seed
        self.members = [TeamMember(i, s, config, vocabulary, seed=seed * 100 + i, device=device)
                        for i, s in enumerate(streams)]
        self.channel_config = channel
        self.channel = Channel(len(streams), channel.success_probability, channel.budget_bytes,
                               seed=zlib.crc32(f"channel-{seed}".encode()))
        self.round_index = 0

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
        local = self.each_member(lambda m: m.local_round(reads[m.index]))
        # ---- exchange -------------------------------------------------------------------------
        start = time.perf_counter()
        sent0, recv0, link0 = self.channel.bytes_sent.copy(), self.channel.bytes_received.copy(), \
            self.channel.link_bytes.copy()
        degree = plan.send_params.sum(axis=1)
        params_in: dict[int, list[ParameterMessage]] = {j: [] for j in range(n)}
        rays_in: dict[int, list[RayMessage]] = {j: [] for j in range(n)}
        deliveries = []
        for i in range(n):
            for j in range(n):
                messages = []
                if plan.send_params[i, j] and self.config.exchange.point_clouds:
                    messages.append(self.members[i].point_cloud_message(j, t))
                elif plan.send_params[i, j]:
                    messages.append(self.members[i].parameter_message(j, t, int(degree[i])))
                if plan.share_rays[i, j]:
                    ray = self.members[i].ray_message(j, t, zlib.crc32(f"rays-{self.seed}-{t}-{i}-{j}".encode()))
                    if ray is not None:
                        messages.append(ray)
                for message in messages:
                    d = self.channel.transmit(message)
                    if d.kind == "params":
                        self.members[i].acknowledge(j, d.status == DELIVERED)
                    deliveries.append({"sender": i, "receiver": j, "kind": d.kind, "status": d.status,
                                       "bytes": d.bytes})
                    if d.status == DELIVERED and d.kind != "points":  # clouds are counted, not learned from
                        (params_in if d.kind == "params" else rays_in)[j].append(d.message)
                        if d.kind != "params":
                            self.members[j].note_rays(d.message)
        exchange_s = time.perf_counter() - start

        # ---- arrival and consistency, each receiver on its own ---------------------------------------
        def receive_and_agree(member: TeamMember) -> tuple[dict, dict, float]:
            t0 = time.perf_counter()
            counts = {"adopted": 0, "matched": 0, "merged": 0, "refit": 0}
            for message in params_in[member.index]:
                for k, v in member.receive_parameters(message).items():
                    counts[k] += v
            arrival = time.perf_counter() - t0
            terms = member.consistency_round(rays_in[member.index])
            return counts, terms, arrival + terms.pop("seconds")

        alignment, losses, consistency_s = {}, {}, []
        for member, (counts, terms, seconds) in zip(self.members, self.each_member(receive_and_agree)):
            alignment[member.name] = counts
            losses[member.name] = {"data": local[member.index].loss,
                                   "local_parameter": local[member.index].parameter, **terms}
            consistency_s.append(seconds)
        self.round_index += 1
        statuses = [d["status"] for d in deliveries]
        return RoundReport(
            round=t, frames_read=[len(r.frames) for r in local], keyframes=[r.keyframes for r in local],
            bytes_per_link=self.channel.link_bytes - link0,
            bytes_sent=(self.channel.bytes_sent - sent0).tolist(),
            bytes_received=(self.channel.bytes_received - recv0).tolist(),
            delivered=statuses.count(DELIVERED), dropped=statuses.count(DROPPED),
            over_budget=statuses.count(OVER_BUDGET), deliveries=deliveries, alignment=alignment, losses=losses,
            local_s=[r.seconds for r in local], consistency_s=consistency_s, exchange_s=max(exchange_s, 0.0),
            done=self.done)

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

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_pool"] = None
        return state

    # ---- checkpoints ------------------------------------------------------------------------------
    def save(self, path: str | Path, extra: dict | None = None) -> Path:
        """The whole team after the last round (maps, keyframes, fusion, what each holds of its peers,
        the channel's counters and draws), written atomically; ``extra`` is stored beside it."""
        return save_checkpoint(path, {"round": self.round_index, "seed": self.seed,
                                      "channel": self.channel.state(), "extra": extra or {},
                                      "members": [member_state(m) for m in self.members]})

    def load(self, path: str | Path) -> dict:
        """Restore a team saved by ``save`` (same streams and config); returns its ``extra``."""
        data = load_checkpoint(path)
        if len(data["members"]) != self.num_agents or data["seed"] != self.seed:
            raise CheckpointError(f"{path}: a team of {len(data['members'])} agents with seed {data['seed']}, "
                                  f"not {self.num_agents} with seed {self.seed}")
        for member, state in zip(self.members, data["members"]):
            restore_member(member, state)
        self.channel.restore(data["channel"])
        self.round_index = data["round"]
        return data["extra"]


__all__ = ["ChannelConfig", "PlanError", "RoundPlan", "RoundReport", "Team"]
