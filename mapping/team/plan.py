"""What a round asks of the channel: the plan (who sends what to whom, which instances) and the links' settings.

``RoundPlan`` is the one thing the env's actions and the CLI's policies hand the team (``Team.round``);
``ChannelConfig`` is the links: success, budget, and links that come and go (``mapping.team.links``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mapping.config_fields import NEUTRAL_DEFAULT, bounded, lengths


class PlanError(ValueError):
    """A round plan of the wrong shape, type or with self-links."""


@dataclass
class RoundPlan:
    """Who sends what to whom this round: two (N, N) bool matrices, diagonal False, and optionally which
    instances: ``send_instances[(i, j)]`` the ids of i's instances its parameter message to j carries (None:
    every shareable one on every link; given, a link without an entry carries none), and ``send_new[i, j]``:
    also the instances that appeared in i's map after its last snapshot (no observation could name them)."""

    send_params: np.ndarray
    share_rays: np.ndarray
    send_instances: dict[tuple[int, int], tuple[int, ...]] | None = None
    send_new: np.ndarray | None = None

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
        chosen = None
        if self.send_instances is not None:
            chosen = {}
            for key, ids in dict(self.send_instances).items():
                if not (isinstance(key, tuple) and len(key) == 2 and all(isinstance(k, (int, np.integer)) for k in key)
                        and 0 <= key[0] < n and 0 <= key[1] < n and key[0] != key[1]):
                    raise PlanError(f"plan.send_instances keys are (sender, receiver) pairs of distinct agents in "
                                    f"0..{n - 1}, got {key!r}")
                values = np.asarray(list(ids))
                if values.size and (values.dtype.kind not in "iu" or values.min() < 0):
                    raise PlanError(f"plan.send_instances[{key}] must hold instance ids (integers >= 0), got "
                                    f"{list(ids)[:5]}")
                chosen[(int(key[0]), int(key[1]))] = tuple(int(v) for v in values)
        new = None
        if self.send_new is not None:
            new = np.asarray(self.send_new)
            if new.shape != (n, n) or not np.all(np.isin(new, (0, 1))):
                raise PlanError(f"plan.send_new must be ({n}, {n}) booleans, got shape {new.shape}")
            new = new.astype(bool) & ~np.eye(n, dtype=bool)
        return RoundPlan(*out, chosen, new)


@dataclass(frozen=True)
class ChannelConfig:
    """The links: success probability per message, an optional budget per agent, and links that come and go
    (``mapping.team.links``: a range along the paths, a capacity per round)."""

    success_probability: float = field(default=1.0, metadata=bounded(0, 1))
    """Chance that each message arrives (drawn per message from the team's seed)."""
    budget_mb: float | None = field(default=None, metadata=bounded(0, 1e9))
    """Megabytes each agent may send over the run (None: unlimited)."""
    link_success: tuple[tuple[float, ...], ...] | None = field(
        default=None, metadata=lengths(1, 256, lengths(1, 256, bounded(0, 1)), also=NEUTRAL_DEFAULT))
    """Per link, the chance that a message from agent i (row) to agent j (column) arrives, an N x N list (the
    diagonal is not used); given, it replaces ``success_probability``."""
    link_range_m: float | None = field(default=None, metadata=bounded(0, 1e6, low_open=True))
    """A link is up only while its two agents are within this many metres (None: always up)."""
    link_mb_per_round: float | None = field(default=None, metadata=bounded(0, 1e6, low_open=True))
    """Megabytes a link carries a round; instances that do not fit wait for a later message (None: no limit)."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.success_probability <= 1.0:
            raise ValueError(f"channel.success_probability must be in [0, 1], got {self.success_probability}")
        if self.budget_mb is not None and not self.budget_mb >= 0:
            raise ValueError(f"channel.budget_mb must be >= 0 or None, got {self.budget_mb}")
        if self.link_success is not None:
            try:
                rows = [[float(v) for v in row] for row in self.link_success]
                flags = any(isinstance(v, bool) for row in self.link_success for v in row)
            except (TypeError, ValueError):
                rows, flags = [], True
            if flags or not rows or any(len(row) != len(rows) for row in rows) or not all(
                    0.0 <= v <= 1.0 for row in rows for v in row):
                raise ValueError("channel.link_success must be an N x N list of probabilities in [0, 1] (row: sender, "
                                 f"column: receiver), got {self.link_success!r}")
        for name in ("link_range_m", "link_mb_per_round"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not (isinstance(value, (int, float, np.number))
                                                                       and np.isfinite(value) and value > 0)):
                raise ValueError(f"channel.{name} must be a finite number > 0 or None (no limit), got {value!r}")

    def success_matrix(self, n: int) -> float | np.ndarray:
        """The success probability of every link of a team of ``n`` (ValueError when ``link_success`` is not n x n)."""
        if self.link_success is None:
            return self.success_probability
        matrix = np.asarray(self.link_success, np.float64)
        if matrix.shape != (n, n):
            raise ValueError(f"channel.link_success is {matrix.shape[0]} x {matrix.shape[1]}, the team has {n} agents")
        return matrix

    @property
    def budget_bytes(self) -> float | None:
        """The budget in bytes (with ``link_capacity_bytes``, the one place MB become bytes)."""
        return None if self.budget_mb is None else self.budget_mb * 1e6

    @property
    def link_capacity_bytes(self) -> float | None:
        """What a link carries a round, in bytes (None: no limit)."""
        return None if self.link_mb_per_round is None else self.link_mb_per_round * 1e6


__all__ = ["ChannelConfig", "PlanError", "RoundPlan"]
