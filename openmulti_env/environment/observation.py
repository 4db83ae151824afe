"""Each agent's observation, from its own knowledge only: its frames, its fields, the messages it sent and
received. Layout and channel meanings: ``openmulti_env.environment.layout`` (policies read it by those names).

``map`` is built here from the agent's snapshot (``mapping.team.AgentSnapshot``) and its own fields read on
a fixed voxel grid over the room's box (``mapping.model.topdown``); ``comm`` from the snapshot's per-peer link
state. Ground truth never enters: ``ProbeRaster`` (the share of the observable ground-truth surface each
cell's samples an agent's map reproduces) feeds ``state()`` for centralised critics only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mapping.team import AgentSnapshot
from mapping.model.topdown import ColumnGrid, ColumnMap
if TYPE_CHECKING:
    from openmulti_env.experiment.tree import EnvSettings, Experiment
from openmulti_env.environment.layout import (AGENT_FEATURES, INSTANCE_FEATURES, LINK_FEATURES, LINK_STATE,
                                              MAP_CHANNELS, SIZE_SCALE_M, age_feature)

OBSERVATION_CHANNELS = MAP_CHANNELS
DEPTH_STRIDE = 4
"""Every this many pixels (both ways) of a depth frame marks the ``observed`` channel."""


@dataclass(frozen=True)
class TopDownGrid:
    """The square raster of the room's floor: cell (row, col) of an (x, y) point."""

    origin_xy: np.ndarray  # (2,) world xy of the grid's corner
    cell_m: float
    size: int

    @staticmethod
    def around(lo_xy: np.ndarray, hi_xy: np.ndarray, size: int, margin_m: float = 0.2) -> "TopDownGrid":
        """A grid of ``size`` x ``size`` cells holding the box [lo, hi] with ``margin_m`` around it."""
        lo, hi = np.asarray(lo_xy, float) - margin_m, np.asarray(hi_xy, float) + margin_m
        cell = float(np.max(hi - lo)) / size
        centre = (lo + hi) / 2
        return TopDownGrid(centre - cell * size / 2, cell, size)

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Row and column indices of (M, 2) points, and which of them fall on the grid."""
        ij = np.floor((np.asarray(xy, float)[:, :2] - self.origin_xy) / self.cell_m).astype(np.int64)
        inside = np.all((ij >= 0) & (ij < self.size), axis=1)
        return ij[:, 1], ij[:, 0], inside  # row = y, col = x

    def column_grid(self, room_height_m: float, step_m: float = 0.05, ceiling_gap_m: float = 0.15) -> ColumnGrid:
        """Voxel centres over the grid's cells from just under the floor to ``ceiling_gap_m`` under the room's
        height, ``step_m`` apart (seen from above, the ceiling would cover the room)."""
        centres = self.origin_xy[:, None] + (np.arange(self.size) + 0.5) * self.cell_m
        zs = np.arange(-0.02, max(room_height_m - ceiling_gap_m, 0.0), step_m)
        return ColumnGrid(centres[0], centres[1], zs)

    def flat(self, xy: np.ndarray) -> np.ndarray:
        """Flat cell indices of the points that fall on the grid."""
        rows, cols, inside = self.cells(xy)
        return rows[inside] * self.size + cols[inside]

    def fill_box(self, plane: np.ndarray, lo_xy: np.ndarray, hi_xy: np.ndarray, value: int) -> None:
        """Set the cells under an axis-aligned box footprint to at least ``value``."""
        r0, c0, _ = self.cells(np.asarray([lo_xy[:2]]))
        r1, c1, _ = self.cells(np.asarray([hi_xy[:2]]))
        r0, r1 = np.clip([r0[0], r1[0]], 0, self.size - 1)
        c0, c1 = np.clip([c0[0], c1[0]], 0, self.size - 1)
        view = plane[r0:r1 + 1, c0:c1 + 1]
        np.maximum(view, value, out=view)


class ProbeRaster:
    """The observable ground-truth surface samples' cells, computed once per world: turns which samples an
    agent's map reproduces into a per-cell share, for ``state()`` (centralised critics) only. Samples on the
    ceiling (``hidden``) stay out: seen from above it would cover the room."""

    def __init__(self, grid: TopDownGrid, points: np.ndarray, hidden: np.ndarray | None = None):
        self.grid = grid
        rows, cols, inside = grid.cells(points)
        if hidden is not None:
            inside = inside & ~np.asarray(hidden, bool)
        self.keep = inside
        self.flat = rows[inside] * grid.size + cols[inside]
        self.count = np.bincount(self.flat, minlength=grid.size ** 2).astype(np.float64)

    def coverage(self, covered: np.ndarray) -> np.ndarray:
        """(H, W) uint8: share of the cell's samples that ``covered`` (P,) marks."""
        hit = np.asarray(covered, bool)[self.keep]
        share = np.bincount(self.flat[hit], minlength=self.grid.size ** 2) / np.maximum(self.count, 1)
        return _u8(share).reshape(self.grid.size, self.grid.size)


class AgentObservation:
    """One agent's accumulating planes (``observed``, path) and the assembly of its observation."""

    def __init__(self, grid: TopDownGrid):
        self.grid = grid
        self.observed = np.zeros((grid.size, grid.size), np.uint8)
        self.path = np.zeros((grid.size, grid.size), np.uint8)

    def add_frames(self, frames) -> None:
        """Mark the cells the frames' depth hits and the camera positions (the agent's own data)."""
        for frame in frames:
            self.observed.reshape(-1)[self.grid.flat(frame.backproject(stride=DEPTH_STRIDE))] = 255
            self.path.reshape(-1)[self.grid.flat(frame.pose[None, :3, 3])] = 128

    def assemble(self, columns: ColumnMap | None, room_height_m: float, received: np.ndarray,
                 position: np.ndarray | None, peers: np.ndarray) -> np.ndarray:
        """The (H, W, 6) uint8 ``map`` (channel order ``MAP_CHANNELS``); ``columns`` None: an empty map."""
        path = self.path.copy()
        if position is not None:
            path.reshape(-1)[self.grid.flat(np.asarray(position)[None])] = 255
        height, decided = map_planes(columns, room_height_m, self.grid.size)
        return np.stack([height, decided, self.observed.copy(), received, path, peers], axis=-1)


def map_planes(columns: ColumnMap | None, room_height_m: float, size: int) -> tuple[np.ndarray, np.ndarray]:
    """``map_height`` (0: nothing; 1..255: floor to room height) and ``map_decided`` of a column map."""
    if columns is None:
        return np.zeros((size, size), np.uint8), np.zeros((size, size), np.uint8)
    top = np.asarray(columns.top, np.float64)
    scaled = np.clip(np.nan_to_num(top, nan=0.0) / max(room_height_m, 1e-6), 0.0, 1.0)
    height = np.where(np.isnan(top), 0, 1 + np.round(scaled * 254)).astype(np.uint8)
    return height, _u8(columns.decided)


def comm_vector(snapshot: AgentSnapshot, num_agents: int, budget_share: float) -> np.ndarray:
    """The ``comm`` entry: ``LINK_FEATURES`` per peer in action order, then ``AGENT_FEATURES``."""
    rows = []
    for peer in (j for j in range(num_agents) if j != snapshot.index):
        link = snapshot.links.get(peer)
        known = snapshot.peers.get(peer)
        values = {
            "holds": link.holds if link else 0.0, "up_to_date": link.up_to_date if link else 0.0,
            "change": link.change if link else 1.0,
            "since_params": age_feature(snapshot.rounds, link.params_round if link else None),
            "since_rays": age_feature(snapshot.rounds, link.rays_round if link else None),
            "since_received": age_feature(snapshot.rounds, known.last_parameters_round if known else None),
            "held_from_peer": min(1.0, (known.held_instances if known else 0) / max(snapshot.instances, 1)),
            "bytes_share": (link.bytes_sent if link else 0) / max(snapshot.bytes_sent_total, 1)}
        rows.extend(values[name] for name in LINK_FEATURES)
    agent = {"budget_left": budget_share, "progress": snapshot.frames_read / max(snapshot.frames_total, 1)}
    rows.extend(agent[name] for name in AGENT_FEATURES)
    return np.clip(np.asarray(rows, np.float32), 0.0, 1.0)


def link_rows(snapshot: AgentSnapshot, num_agents: int, capacity_bytes: float | None) -> np.ndarray:
    """The ``links`` entry: (N - 1, ``LINK_STATE``) per peer in action order (``layout``)."""
    out = np.zeros((num_agents - 1, len(LINK_STATE)), np.float32)
    for k, peer in enumerate(j for j in range(num_agents) if j != snapshot.index):
        up = snapshot.links_up.get(peer, True)
        room = 1.0 if capacity_bytes is None else capacity_bytes / max(snapshot.map_bytes, 1)
        out[k] = (float(up), min(1.0, room) if up else 0.0)
    return out


def instance_rows(snapshot: AgentSnapshot, num_agents: int, slots: int, capacity_bytes: float | None) -> np.ndarray:
    """The ``instances`` entry: (N - 1, slots, ``INSTANCE_FEATURES``), each peer's first ``slots`` instances in the
    link's priority order (``mapping.team.report.priority_order``)."""
    out = np.zeros((num_agents - 1, slots, len(INSTANCE_FEATURES)), np.float32)
    rounds = snapshot.rounds
    room = capacity_bytes if capacity_bytes is not None else max(snapshot.map_bytes, 1)
    for k, peer in enumerate(j for j in range(num_agents) if j != snapshot.index):
        for m, item in enumerate(snapshot.instance_links.get(peer, ())[:slots]):
            values = {"present": 1.0, "lacks": float(item.lacks), "change": item.change,
                      "copy_age": age_feature(rounds, item.copy_round), "shared": float(item.shared),
                      "confidence": item.confidence, "size": item.diagonal_m / SIZE_SCALE_M,
                      "age": age_feature(rounds, item.born_round - 1), "bytes": item.nbytes / room}
            out[k, m] = [values[name] for name in INSTANCE_FEATURES]
    return np.clip(out, 0.0, 1.0)


def slot_instances(snapshot: AgentSnapshot, num_agents: int, slots: int) -> list[list[int]]:
    """Per peer in action order, the instance ids in its ``slots`` slots (what the instance action form sends)."""
    return [[item.instance_id for item in snapshot.instance_links.get(peer, ())[:slots]]
            for peer in range(num_agents) if peer != snapshot.index]


def peer_plane(grid: TopDownGrid, known: dict[int, tuple[int, np.ndarray]], step: int) -> np.ndarray:
    """``peer_poses``: 255 at each peer's last known position, fading by 32 per step of age (at least 64)."""
    plane = np.zeros((grid.size, grid.size), np.uint8)
    for _, (when, position) in known.items():
        value = max(64, 255 - 32 * max(step - when, 0))
        cell = grid.flat(np.asarray(position)[None])
        plane.reshape(-1)[cell] = np.maximum(plane.reshape(-1)[cell], value)
    return plane


def received_plane(grid: TopDownGrid, boxes: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """``received``: 255 under the footprint of every instance box held from a peer."""
    plane = np.zeros((grid.size, grid.size), np.uint8)
    for lo, hi in boxes:
        grid.fill_box(plane, lo, hi, 255)
    return plane


def _u8(x: np.ndarray) -> np.ndarray:
    return np.round(np.clip(x, 0.0, 1.0) * 255).astype(np.uint8)


def observed_slots(env: "EnvSettings", action_form: str) -> int:
    """Instance slots per peer in the observation: ``env.instance_slots`` in the instances action form, none in the
    others (the env's spaces and ``openmulti run``'s observing policies follow this one rule)."""
    return env.instance_slots if action_form == "instances" else 0


def team_observer(tree: "Experiment", room_size_m, action_form: str) -> "TeamObserver":
    """The observation builder of ``tree``'s episode in a room of ``room_size_m`` (x, y, z) from the origin: its map
    size, byte budget, link capacity and instance slots (``observed_slots``)."""
    return TeamObserver(np.zeros(3), np.asarray(room_size_m, float), tree.env.map_size, tree.channel.budget_bytes,
                        tree.channel.link_capacity_bytes, observed_slots(tree.env, action_form))


class TeamObserver:
    """Every agent's observation over a team's rounds: the env's and ``openmulti run``'s one builder.

    ``room_lo``/``room_hi`` are the room's box (x, y, z): the extent an agent knows it maps in, which fixes
    the grid; everything else comes from the team's snapshots and each agent's own fields."""

    def __init__(self, room_lo: np.ndarray, room_hi: np.ndarray, map_size: int, budget_bytes: float | None,
                 link_capacity_bytes: float | None = None, instance_slots: int = 0):
        lo, hi = np.asarray(room_lo, float), np.asarray(room_hi, float)
        self.link_capacity_bytes, self.instance_slots = link_capacity_bytes, instance_slots
        self.grid = TopDownGrid.around(lo[:2], hi[:2], map_size)
        self.room_height = float(hi[2] - lo[2])
        self.column_grid = self.grid.column_grid(self.room_height)
        self.budget_bytes = budget_bytes
        self.observers: list[AgentObservation] = []
        self.columns: list[ColumnMap | None] = []

    def reset(self, num_agents: int) -> None:
        """A new episode: empty maps and paths."""
        self.observers = [AgentObservation(self.grid) for _ in range(num_agents)]
        self.columns = [None] * num_agents

    def update(self, team, snapshots: list[AgentSnapshot]) -> None:
        """After a round: each agent's new frames and its fields read on the column grid."""
        for observer, snapshot in zip(self.observers, snapshots):
            observer.add_frames(list(snapshot.new_frames))
        self.columns = team.column_maps(self.column_grid)

    def observe(self, snapshot: AgentSnapshot) -> dict[str, np.ndarray]:
        """The agent's ``{"map", "comm", "links"[, "instances"]}`` observation (``layout``)."""
        boxes = [box for peer in snapshot.peers.values() for box in peer.held_object_boxes]
        known = {p: k.position for p, k in snapshot.peers.items() if k.position is not None}
        peers = peer_plane(self.grid, known, snapshot.rounds - 1)
        planes = self.observers[snapshot.index].assemble(self.columns[snapshot.index], self.room_height,
                                                         received_plane(self.grid, boxes), snapshot.position, peers)
        n = len(self.observers)
        out = {"map": planes, "comm": comm_vector(snapshot, n, self.budget_share(snapshot)),
               "links": link_rows(snapshot, n, self.link_capacity_bytes)}
        if self.instance_slots:
            out["instances"] = instance_rows(snapshot, n, self.instance_slots, self.link_capacity_bytes)
        return out

    def budget_share(self, snapshot: AgentSnapshot) -> float:
        """Share of the agent's byte budget left (1 without a budget)."""
        if self.budget_bytes is None:
            return 1.0
        return float(snapshot.budget_left_bytes / self.budget_bytes) if self.budget_bytes > 0 else 0.0
