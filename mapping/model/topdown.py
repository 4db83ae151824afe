"""A top-down reading of one agent's own map: its fields queried on a fixed grid of columns.

A robot deciding whom to talk to can only know what its own map holds. This reads that map the way a
planner would, without any ground truth: every instance's occupancy is evaluated at the voxel centres of
a fixed (rows, cols, levels) grid that fall inside the instance's box (outside every box the map is
empty, as for meshing, and so is space away from the surface the instance observed), and each column is
summarised by the top of what the map holds there and by how much of the column the map decides (a voxel
no ray of the instance's looked at is undecided). The grid is regular, so an instance's voxels are index ranges: no
point-in-box search over the whole grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

DECIDED_MARGIN = 0.25
"""A voxel is decided when its occupancy is at least this far from 0.5 (below 0.25 or above 0.75)."""


@dataclass(frozen=True)
class ColumnGrid:
    """Voxel centres of a regular grid: ``xs`` (W,) columns, ``ys`` (H,) rows, ``zs`` (Z,) levels, ascending."""

    xs: np.ndarray
    ys: np.ndarray
    zs: np.ndarray

    def __post_init__(self) -> None:
        for name in ("xs", "ys", "zs"):
            axis = np.asarray(getattr(self, name), np.float64)
            if axis.ndim != 1 or len(axis) < 1 or (len(axis) > 1 and np.any(np.diff(axis) <= 0)):
                raise ValueError(f"ColumnGrid.{name} must be a non-empty ascending 1-D array, got shape {axis.shape}")

    def index_range(self, axis: np.ndarray, lo: float, hi: float) -> tuple[int, int]:
        """[start, stop) of the centres of ``axis`` within [lo, hi]."""
        return int(np.searchsorted(axis, lo, "left")), int(np.searchsorted(axis, hi, "right"))


@dataclass(frozen=True)
class ColumnMap:
    """Per column (H, W): what one agent's map holds there."""

    top: np.ndarray
    """Height (m) of the highest occupied voxel; NaN where the map holds nothing occupied."""
    decided: np.ndarray
    """Share of the column's voxels whose occupancy is decided (``DECIDED_MARGIN``) by some instance."""


@torch.no_grad()
def column_map(mapper, grid: ColumnGrid, level: float = 0.5) -> ColumnMap:
    """Query every live instance of ``mapper`` (a ``MappingAgent``) on the voxels of ``grid`` inside its box.

    A voxel covered by several instances takes the largest occupancy (the union of the instances, as the
    scene mesh is the union of their meshes) and counts as decided when any of them decides it."""
    xs, ys, zs = (np.asarray(a, np.float64) for a in (grid.xs, grid.ys, grid.zs))
    shape = (len(ys), len(xs), len(zs))
    occupancy = torch.zeros(int(np.prod(shape)), device=mapper.device)
    decided = torch.zeros(int(np.prod(shape)), dtype=torch.bool, device=mapper.device)
    for name, bank in mapper.banks.items():
        slots = [s for s in mapper.slots.values() if s.bank == name and s.alive]
        points, rows, flat = [], [], []
        for slot in slots:
            voxels = _box_voxels(grid, bank, slot.row)
            if voxels is None:
                continue
            r, c, k = (a.ravel() for a in voxels)
            points.append(np.stack([xs[c], ys[r], zs[k]], axis=1))
            rows.append(np.full(len(r), slot.row))
            flat.append(np.ravel_multi_index((r, c, k), shape))
        if not points:
            continue
        field = mapper.observed_field(name)  # surface only near what the instance observed
        queried = torch.as_tensor(np.concatenate(points), dtype=torch.float32, device=mapper.device)
        row_index = torch.as_tensor(np.concatenate(rows), dtype=torch.long, device=mapper.device)
        out = field.query(queried, row_index, with_colour=False).occupancy
        index = torch.as_tensor(np.concatenate(flat), dtype=torch.long, device=mapper.device)
        occupancy.scatter_reduce_(0, index, out, reduce="amax")
        sure = ((out - 0.5).abs() >= DECIDED_MARGIN) & field.looked(queried, row_index)  # nobody looked: undecided
        decided.index_fill_(0, index[sure], True)
    occupied = (occupancy > level).reshape(shape).cpu().numpy()
    any_occupied = occupied.any(axis=2)
    top_level = len(zs) - 1 - np.argmax(occupied[:, :, ::-1], axis=2)
    top = np.where(any_occupied, zs[top_level], np.nan)
    return ColumnMap(top, decided.reshape(shape).float().mean(dim=2).cpu().numpy())


@dataclass(frozen=True)
class InstanceColumns:
    """What one instance alone puts in the columns of a ``ColumnGrid``: the columns its box covers (flat row-major
    indices), the top of its occupied voxels there (NaN: none) and the share of each column it decides."""

    columns: np.ndarray
    top: np.ndarray
    decided: np.ndarray


@torch.no_grad()
def instance_columns(mapper, grid: ColumnGrid, level: float = 0.5) -> dict[int, InstanceColumns]:
    """``column_map`` one live instance at a time (a recorded episode adds a held copy's columns to a receiver's
    map, ``mapping.team.recorded``): the union's ``top`` is the largest of these; its ``decided`` is at most their sum."""
    xs, ys, zs = (np.asarray(a, np.float64) for a in (grid.xs, grid.ys, grid.zs))
    out = {}
    for name, bank in mapper.banks.items():
        for iid, slot in sorted((i, s) for i, s in mapper.slots.items() if s.bank == name and s.alive):
            voxels = _box_voxels(grid, bank, slot.row)
            if voxels is None:
                continue
            r, c, k = voxels
            queried = torch.as_tensor(np.stack([xs[c.ravel()], ys[r.ravel()], zs[k.ravel()]], axis=1),
                                      dtype=torch.float32, device=mapper.device)
            rows = torch.full((len(queried),), slot.row, dtype=torch.long, device=mapper.device)
            field = mapper.observed_field(name)
            occ = field.query(queried, rows, with_colour=False).occupancy
            sure = (((occ - 0.5).abs() >= DECIDED_MARGIN) & field.looked(queried, rows)).cpu().numpy()
            occupied = (occ > level).cpu().numpy().reshape(r.shape)
            levels = zs[k[0, 0]]
            top = np.where(occupied.any(axis=2), levels[len(levels) - 1 - np.argmax(occupied[:, :, ::-1], axis=2)], np.nan)
            out[iid] = InstanceColumns((r[:, :, 0] * len(xs) + c[:, :, 0]).ravel().astype(np.int32),
                                       top.ravel().astype(np.float32),
                                       (sure.reshape(r.shape).sum(axis=2) / len(zs)).ravel().astype(np.float32))
    return out


def _box_voxels(grid: ColumnGrid, bank, row: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(rows, cols, levels) index arrays, each (R, C, L), of the grid voxels inside instance ``row``'s box (None:
    none)."""
    xs, ys, zs = (np.asarray(a, np.float64) for a in (grid.xs, grid.ys, grid.zs))
    lo, hi = bank.bound_min[row].cpu().numpy(), bank.bound_max[row].cpu().numpy()
    (c0, c1), (r0, r1), (l0, l1) = (grid.index_range(xs, lo[0], hi[0]), grid.index_range(ys, lo[1], hi[1]),
                                    grid.index_range(zs, lo[2], hi[2]))
    if c1 <= c0 or r1 <= r0 or l1 <= l0:
        return None
    return tuple(np.meshgrid(np.arange(r0, r1), np.arange(c0, c1), np.arange(l0, l1), indexing="ij"))
