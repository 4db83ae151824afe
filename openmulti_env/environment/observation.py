"""Each agent's observation: a fixed-size top-down map of its own reconstruction and what it knows.

Layout: ``(H, W, C)`` uint8 in [0, 255], channels last: SB3 takes it as an image (it transposes
channels-last images itself), RLlib's CNN encoders want channels last, TorchRL takes any Box. Rows run
along +y of the room, columns along +x; the room's floor box fills the square with a margin, aspect
kept. The channels (``OBSERVATION_CHANNELS``):

0. ``map_height``: the highest point of the agent's map per cell (top of the room = 255), read where its
   fields reproduce the probed surface samples (``mapping.evaluate.probe``; the ceiling left out);
1. ``map_coverage``: share of the cell's probed surface samples its map reproduces;
2. ``observed``: cells its own depth frames have hit (its own coverage, whatever it learned);
3. ``received``: footprints of the instance boxes it holds from peers (parameters received);
4. ``own_path``: its path so far (128) and its current position (255);
5. ``peer_poses``: peers' last known positions, from the ray messages it received (255, fading by 32
   per step since);
6. ``budget_left``: the share of its byte budget left, as a constant plane (255 with no budget).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

OBSERVATION_CHANNELS = ("map_height", "map_coverage", "observed", "received", "own_path", "peer_poses",
                        "budget_left")
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
    """The surface probes' cells, computed once per world: turns per-probe coverage into the two map
    channels. Probes on the ceiling (``hidden``) stay out: seen from above it would cover the room."""

    def __init__(self, grid: TopDownGrid, points: np.ndarray, room_height_m: float,
                 hidden: np.ndarray | None = None):
        self.grid = grid
        rows, cols, inside = grid.cells(points)
        if hidden is not None:
            inside = inside & ~np.asarray(hidden, bool)
        self.keep = inside
        self.flat = rows[inside] * grid.size + cols[inside]
        self.height = np.clip(points[inside, 2] / max(room_height_m, 1e-6), 0, 1)
        self.count = np.bincount(self.flat, minlength=grid.size ** 2).astype(np.float64)

    def channels(self, covered: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) uint8 ``map_height`` and ``map_coverage`` of a (P,) coverage vector."""
        hit = np.asarray(covered, bool)[self.keep]
        n = self.grid.size ** 2
        height = np.zeros(n)
        np.maximum.at(height, self.flat[hit], self.height[hit])
        share = np.bincount(self.flat[hit], minlength=n) / np.maximum(self.count, 1)
        side = (self.grid.size, self.grid.size)
        return _u8(height).reshape(side), _u8(share).reshape(side)


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

    def assemble(self, map_height: np.ndarray, map_coverage: np.ndarray, received: np.ndarray,
                 position: np.ndarray | None, peers: np.ndarray, budget_share: float) -> np.ndarray:
        """The (H, W, 7) uint8 observation (channel order ``OBSERVATION_CHANNELS``)."""
        path = self.path.copy()
        if position is not None:
            path.reshape(-1)[self.grid.flat(np.asarray(position)[None])] = 255
        budget = np.full_like(path, _u8(np.asarray(budget_share)))
        return np.stack([map_height, map_coverage, self.observed.copy(), received, path, peers, budget], axis=-1)


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
