"""Links that come and go: which links are up this round (range along the agents' paths) and how many bytes
each can still carry (a per-round capacity), the two limits of ``ChannelConfig``.

Range, as MAANS, VMAS and MPE limit who can talk: a link is up only while its two agents' cameras are within
``link_range_m`` of each other (their positions at the end of the round's frames). Nothing is sent over a
link that is down and it costs nothing. Capacity: a link carries at most ``link_mb_per_round`` a round; a
parameter message keeps, in the sender's priority order (``Outbox.instance_priority``), each instance that still
fits and leaves the rest out: they are neither sent nor charged, and since the sender books only what arrived, they
lead its next message to that peer (they wait, they are not queued on their own).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class LinkLimits:
    """This round's link state, (N, N) each: ``up[i, j]`` the link i -> j may carry anything; ``room_bytes[i, j]``
    what it can still carry (inf: no capacity limit)."""

    up: np.ndarray
    room_bytes: np.ndarray

    @staticmethod
    def unlimited(n: int) -> "LinkLimits":
        return LinkLimits(~np.eye(n, dtype=bool), np.full((n, n), np.inf))

    def as_dict(self) -> dict:
        """The JSON form (``rounds.json``): up as 0/1, room in bytes (null for no limit)."""
        room = [[None if not np.isfinite(v) else int(v) for v in row] for row in self.room_bytes]
        return {"up": self.up.astype(int).tolist(), "room_bytes": room}


def links_in_range(positions: np.ndarray, range_m: float | None) -> np.ndarray:
    """(N, N) bool: pairs of (N, 3) positions within ``range_m`` (every pair with None); diagonal False."""
    positions = np.asarray(positions, np.float64)
    n = len(positions)
    if range_m is None:
        return ~np.eye(n, dtype=bool)
    distance = np.linalg.norm(positions[:, None, :] - positions[None, :, :], axis=-1)
    return (distance <= range_m) & ~np.eye(n, dtype=bool)


def round_limits(positions: np.ndarray, range_m: float | None, capacity_bytes: float | None) -> LinkLimits:
    """The links of a round from the agents' positions and the two limits (``ChannelConfig.link_capacity_bytes``)."""
    up = links_in_range(positions, range_m)
    room = np.full(up.shape, np.inf if capacity_bytes is None else capacity_bytes)
    room[~up] = 0.0
    return LinkLimits(up, room)


def closest_approach_m(paths: Sequence[np.ndarray]) -> np.ndarray:
    """(N, N) the smallest distance between agents i and j at the same frame index along their (F_i, 3) paths
    (a path that ended stays at its last position): a range at which every pair meets is at least its
    largest off-diagonal entry."""
    n = len(paths)
    length = max(len(p) for p in paths)
    padded = np.stack([np.concatenate([p, np.repeat(p[-1:], length - len(p), axis=0)]) for p in paths])
    out = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            out[i, j] = out[j, i] = float(np.linalg.norm(padded[i] - padded[j], axis=-1).min())
    return out


__all__ = ["LinkLimits", "closest_approach_m", "links_in_range", "round_limits"]
