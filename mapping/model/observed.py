"""Observed space per instance: which cells of its box some keyframe's rays have looked at.

An instance's network is trained only where rays passed; elsewhere inside its box it is free to
invent surface, and meshing, rendering and the depth check then draw it (issue 44: 37-87 % of the
pixels off by more than 5 cm were such surface). So each instance keeps a coarse grid of its box on a
world-aligned lattice (``cell_m``; a mapper's: ``MappingConfig.observed_cell_m``), each cell ``UNKNOWN``,
``FREE`` (a ray crossed it before reaching its depth) or ``SURFACE`` (a depth point of the instance fell in it). Cells on one
world lattice make two agents' grids of one object merge cell by cell (the element-wise maximum:
surface over free over unknown), whatever frames their networks use.

On the wire a grid is its lattice origin and shape and 2 bits per cell, zlib-compressed
(``to_bytes`` / ``from_bytes``): mostly unknown or free, it compresses to a small share of the network.
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

UNKNOWN, FREE, SURFACE = 0, 1, 2
CELL_M = 0.05
"""Lattice spacing of ``ObservedSpace.empty`` when none is given (a mapper's is ``MappingConfig.observed_cell_m``)."""
SURFACE_REACH_CELLS = 1
"""A mesh, a rendered view or an observation may hold surface only within this many cells (26-connected) of
a ``SURFACE`` cell: a network's 0.5 level lies within a few cm of the depth points it was trained on, and a
surface cut by its cell's face continues into the neighbour."""
MAX_CELLS = 1 << 24
"""The largest grid a message may announce (a 12 m x 12 m x 3 m room at 5 cm is 3.5 M cells)."""
LATTICE_LIMIT = 1 << 40
"""The largest |lattice index| a grid may use: 2^40 cells of 1 mm reach a billion km, so a corner beyond it is
corrupt or hostile, and sums of two indices stay far inside int64."""
GRID_HEADER = struct.Struct("<d3q3q")
"""A grid's wire header: cell_m, origin (3), shape (3)."""


class ObservedSpaceError(ValueError):
    """Bytes that are not an observed-space grid, one outside the receiver's limits, or a grid too large to keep."""


@dataclass(frozen=True)
class GridHeader:
    """What a grid's wire header announces, checked, in Python integers (no int64 overflow)."""

    cell_m: float
    origin: tuple[int, int, int]
    shape: tuple[int, int, int]

    @property
    def cells(self) -> int:
        return math.prod(self.shape)


def grid_header(data: bytes | memoryview, cell_m: float | None = None, max_cells: int = MAX_CELLS) -> GridHeader:
    """The header of a grid's wire bytes, read without decoding its cells: a positive cell (``cell_m`` if
    given), at most ``max_cells`` cells, an origin within ``LATTICE_LIMIT``; ObservedSpaceError otherwise."""
    if len(data) < GRID_HEADER.size:
        raise ObservedSpaceError(f"observed space of {len(data)} bytes: shorter than its header")
    cell, *rest = GRID_HEADER.unpack_from(data)
    origin, shape = (rest[0], rest[1], rest[2]), (rest[3], rest[4], rest[5])
    if not (math.isfinite(cell) and cell > 0) or (cell_m is not None and cell != cell_m):
        raise ObservedSpaceError(f"observed space: cell size {cell}, expected {cell_m}")
    if any(s < 0 for s in shape) or math.prod(shape) > max_cells:
        raise ObservedSpaceError(f"observed space: shape {list(shape)} out of bounds (at most {max_cells} cells)")
    if any(abs(o) > LATTICE_LIMIT for o in origin):
        raise ObservedSpaceError(f"observed space: origin {list(origin)} out of bounds (lattice indices within "
                                 f"+-2^40)")
    return GridHeader(float(cell), origin, shape)


def lattice_cell(x: float, cell_m: float) -> int:
    """The lattice index of world coordinate ``x`` (``cells_of`` for one value, as a Python integer);
    ObservedSpaceError beyond ``LATTICE_LIMIT``, where int64 lattice arithmetic could overflow."""
    index = float(x) / cell_m
    if not (math.isfinite(index) and abs(index) <= LATTICE_LIMIT):
        raise ObservedSpaceError(f"a coordinate of {x} m lies beyond the lattice (+-2^40 cells of {cell_m} m)")
    return math.floor(index)


def box_cells(lo, hi, cell_m: float) -> tuple[list[int], list[int]]:
    """The first and last lattice cell of the world box [lo, hi] per axis, as Python integers."""
    return [lattice_cell(x, cell_m) for x in lo], [lattice_cell(x, cell_m) for x in hi]


@dataclass
class ObservedSpace:
    """One instance's observed cells: ``states[i, j, k]`` is lattice cell ``origin + (i, j, k)``."""

    cell_m: float
    origin: np.ndarray  # (3,) int64 lattice index of states[0, 0, 0]
    states: np.ndarray  # (X, Y, Z) uint8 of UNKNOWN / FREE / SURFACE
    _reach: np.ndarray | None = field(default=None, repr=False, compare=False)
    """Cached ``SURFACE`` dilated by ``SURFACE_REACH_CELLS`` (None: stale)."""

    @classmethod
    def empty(cls, cell_m: float = CELL_M) -> "ObservedSpace":
        if not (np.isfinite(cell_m) and cell_m > 0):
            raise ValueError(f"cell_m must be a positive number, got {cell_m}")
        return cls(float(cell_m), np.zeros(3, np.int64), np.zeros((0, 0, 0), np.uint8))

    # ---- the lattice ------------------------------------------------------------------------------------
    def cells_of(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) int64 lattice cells of (n, 3) world points."""
        return np.floor(np.asarray(points, np.float64) / self.cell_m).astype(np.int64)

    @property
    def lo(self) -> np.ndarray:
        """(3,) world corner of the grid's first cell."""
        return self.origin * self.cell_m

    @property
    def observed_share(self) -> float:
        """Share of the grid's cells some ray looked at (0 for an empty grid)."""
        return float(np.mean(self.states > UNKNOWN)) if self.states.size else 0.0

    def cover(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """Grow the grid (keeping its states) to hold the world box [lo, hi]."""
        self.cover_cells(*box_cells(lo, hi, self.cell_m))

    def cover_cells(self, first: list[int], last: list[int]) -> None:
        """Grow the grid (keeping its states) to hold lattice cells ``first``..``last`` (inclusive, per axis; Python
        integers, so a far corner cannot overflow); ObservedSpaceError, nothing changed, past ``MAX_CELLS``."""
        if self.states.size:
            origin = self.origin.tolist()
            first = [min(f, o) for f, o in zip(first, origin)]
            last = [max(x, o + n - 1) for x, o, n in zip(last, origin, self.states.shape)]
        shape = tuple(b - a + 1 for a, b in zip(first, last))
        if self.states.size and first == self.origin.tolist() and shape == self.states.shape:
            return
        if min(shape) < 1 or math.prod(shape) > MAX_CELLS:
            raise ObservedSpaceError(f"an observed-space grid of {shape} cells is empty or exceeds {MAX_CELLS} (cells "
                                     f"{first}..{last} at {self.cell_m} m)")
        grown = np.zeros(shape, np.uint8)
        first = np.array(first, np.int64)
        if self.states.size:
            at = self.origin - first
            grown[at[0]:at[0] + self.states.shape[0], at[1]:at[1] + self.states.shape[1],
                  at[2]:at[2] + self.states.shape[2]] = self.states
        self.origin, self.states, self._reach = first, grown, None

    def _index(self, points: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        """Which of ``points`` fall in the grid, and their (i, j, k) indices."""
        idx = self.cells_of(points) - self.origin
        inside = np.all((idx >= 0) & (idx < np.array(self.states.shape)), axis=1) if self.states.size else \
            np.zeros(len(idx), bool)
        return inside, tuple(idx[inside].T)

    # ---- marking and reading ----------------------------------------------------------------------------
    def mark(self, points: np.ndarray, state: int) -> None:
        """Raise the cells of ``points`` (inside the grid) to at least ``state``."""
        inside, ijk = self._index(points)
        if inside.any():
            # the reach depends only on SURFACE cells: marking FREE keeps it, new SURFACE cells add their own
            # neighbourhoods to it (the dilation of a union is the union of the dilations); redoing the whole
            # dilation after every mark was a tenth of an ``rl_small`` step
            if state >= SURFACE and self._reach is not None:
                new = self.states[ijk] != SURFACE
                if new.any():
                    self._reach = _grown_reach(self._reach, np.stack(ijk, axis=1)[new])
            np.maximum.at(self.states, ijk, np.uint8(state))

    def mark_rays(self, origins: np.ndarray, ends: np.ndarray, stop_short_m: float) -> None:
        """``FREE`` along each segment origin -> end (world, (n, 3) each), stopping ``stop_short_m`` before
        its end (the depth's noise), sampled at half a cell; cells outside the grid are skipped."""
        origins, ends = np.asarray(origins, np.float64), np.asarray(ends, np.float64)
        if not len(origins) or not self.states.size:
            return
        direction = ends - origins
        length = np.linalg.norm(direction, axis=1)
        usable = length > stop_short_m
        origins, direction, length = origins[usable], direction[usable] / length[usable, None], length[usable]
        lo, hi = self.lo, self.lo + np.array(self.states.shape) * self.cell_m
        # only the part of each segment inside the grid's box is sampled (slab test)
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (lo - origins) / direction
            t1 = (hi - origins) / direction
        near = np.nanmax(np.where(np.isfinite(t0), np.minimum(t0, t1), -np.inf), axis=1).clip(min=0.0)
        far = np.nanmin(np.where(np.isfinite(t1), np.maximum(t0, t1), np.inf), axis=1)
        far = np.minimum(far, length - stop_short_m)
        step = self.cell_m / 2
        counts = np.ceil(np.maximum(far - near, 0.0) / step).astype(np.int64)
        ray = np.repeat(np.arange(len(counts)), counts)
        t = near[ray] + (np.arange(len(ray)) - np.repeat(np.cumsum(counts) - counts, counts)) * step
        self.mark(origins[ray] + t[:, None] * direction[ray], FREE)

    def state_at(self, points: np.ndarray) -> np.ndarray:
        """(n,) uint8 state of each world point's cell (``UNKNOWN`` outside the grid)."""
        out = np.zeros(len(points), np.uint8)
        inside, ijk = self._index(points)
        out[inside] = self.states[ijk]
        return out

    def surface_reach(self) -> np.ndarray:
        """(X, Y, Z) bool: cells within ``SURFACE_REACH_CELLS`` of a ``SURFACE`` cell (cached until a change)."""
        from scipy.ndimage import binary_dilation  # noqa: PLC0415

        if self._reach is None:
            surface = self.states == SURFACE
            self._reach = (binary_dilation(surface, np.ones((3, 3, 3), bool), iterations=SURFACE_REACH_CELLS)
                           if SURFACE_REACH_CELLS and surface.any() else surface)
        return self._reach

    def near_surface(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: the point's cell is within ``SURFACE_REACH_CELLS`` of a ``SURFACE`` cell: where a mesh,
        a rendered view or an observation may hold surface (``False`` outside the grid)."""
        out = np.zeros(len(points), bool)
        if not self.states.size:
            return out
        inside, ijk = self._index(points)
        out[inside] = self.surface_reach()[ijk]
        return out

    def merge(self, other: "ObservedSpace") -> None:
        """Add ``other``'s observations (same lattice): the cell-wise maximum."""
        if other.cell_m != self.cell_m:
            raise ObservedSpaceError(f"observed spaces of {other.cell_m} m and {self.cell_m} m cells do not merge")
        if not other.states.size:
            return
        origin = other.origin.tolist()
        self.cover_cells(origin, [o + n - 1 for o, n in zip(origin, other.states.shape)])
        at = other.origin - self.origin
        view = self.states[at[0]:at[0] + other.states.shape[0], at[1]:at[1] + other.states.shape[1],
                           at[2]:at[2] + other.states.shape[2]]
        np.maximum(view, other.states, out=view)
        self._reach = None

    def copy(self) -> "ObservedSpace":
        return ObservedSpace(self.cell_m, self.origin.copy(), self.states.copy())

    # ---- the wire ---------------------------------------------------------------------------------------
    def to_bytes(self) -> bytes:
        """Lattice origin and shape, then 2 bits per cell, zlib-compressed."""
        flat = self.states.reshape(-1)
        padded = np.zeros(-(-len(flat) // 4) * 4, np.uint8)
        padded[:len(flat)] = flat
        quads = padded.reshape(-1, 4)
        packed = (quads[:, 0] | quads[:, 1] << 2 | quads[:, 2] << 4 | quads[:, 3] << 6).astype(np.uint8)
        header = GRID_HEADER.pack(self.cell_m, *self.origin.tolist(), *self.states.shape)
        return header + zlib.compress(packed.tobytes(), 6)

    @classmethod
    def from_bytes(cls, data: bytes, cell_m: float | None = None, max_cells: int = MAX_CELLS) -> "ObservedSpace":
        """Inverse of ``to_bytes``; ObservedSpaceError for bytes that are not one (or of another ``cell_m``).
        Nothing beyond the announced cells is inflated (no zip bomb), and the header is checked first."""
        header = grid_header(data, cell_m, max_cells)
        n = header.cells
        want = -(-n // 4)
        try:
            decompressor = zlib.decompressobj()
            raw = decompressor.decompress(data[GRID_HEADER.size:], want + 1)  # bounded: no zip bomb
        except zlib.error as exc:
            raise ObservedSpaceError(f"observed space: corrupt cells ({exc})") from None
        if len(raw) != want or decompressor.unconsumed_tail or not decompressor.eof:
            raise ObservedSpaceError(f"observed space: {len(raw)} bytes of cells{'' if decompressor.eof else ' (cut)'}"
                                     f", expected {want}")
        return cls(header.cell_m, np.array(header.origin, np.int64), unpacked_states(raw, header.shape))


def unpacked_states(raw: bytes, shape: tuple[int, int, int]) -> np.ndarray:
    """The (X, Y, Z) uint8 states of 2-bit packed cells (four a byte), written into the grid's one array with
    no temporary larger than the packed bytes: a message's grids are its largest allocation."""
    packed = np.frombuffer(raw, np.uint8)
    if np.any(packed & (packed >> 1) & 0x55):  # some 2-bit cell is 3: not unknown / free / surface
        raise ObservedSpaceError("observed space: a cell state outside unknown / free / surface")
    cells = np.empty((len(packed), 4), np.uint8)
    for k in range(4):
        np.right_shift(packed, 2 * k, out=cells[:, k])
        cells[:, k] &= 3
    return cells.reshape(-1)[:math.prod(shape)].reshape(shape)


_REACH_OFFSETS = np.stack(np.meshgrid(*[np.arange(-SURFACE_REACH_CELLS, SURFACE_REACH_CELLS + 1)] * 3,
                                      indexing="ij"), axis=-1).reshape(-1, 3)
"""The cube of cells ``binary_dilation`` with a 3x3x3 element, ``SURFACE_REACH_CELLS`` times, adds around a cell."""


def _grown_reach(reach: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """A copy of ``reach`` with the neighbourhood of each (n, 3) cell set (clipped to the grid, as the dilation's
    zero border clips): callers may hold the old array, so it is not changed."""
    near = (cells[:, None, :] + _REACH_OFFSETS[None]).reshape(-1, 3)
    near = near[np.all((near >= 0) & (near < np.array(reach.shape)), axis=1)]
    grown = reach.copy()
    grown[tuple(near.T)] = True
    return grown


def observe_frame(space: ObservedSpace, points: np.ndarray, camera: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                  free_ends: np.ndarray | None = None, stop_short_m: float = 0.05) -> None:
    """Mark one keyframe in an instance's ``space``: grow it to the instance's box [lo, hi], ``FREE``
    along the rays from ``camera`` ((3,) world) to ``free_ends`` (depth points of any pixel whose ray
    crosses the box; default ``points``), stopping ``stop_short_m`` short, then ``SURFACE`` at the
    instance's own depth ``points`` (so a surface cell is never cleared by a grazing ray)."""
    space.cover(lo, hi)
    ends = points if free_ends is None else free_ends
    if len(ends):
        space.mark_rays(np.broadcast_to(camera, ends.shape), ends, stop_short_m)
    if len(points):
        space.mark(points, SURFACE)
