"""A map's fields read only where someone looked: occupancy forced to zero outside each instance's observed
reach (``ObservedSpace.surface_reach``), and mesh faces kept only inside it.

Every reader of a map goes through these: meshing (``observed_faces``), rendered views, the env's top-down
observation and the reward's probe (``ObservedRows``), so a network's invention inside its box, where no
ray passed, is drawn nowhere (issue 44). An instance without an observed space (the setting off, a global
map, an older checkpoint) is read as before.
"""

from __future__ import annotations

from typing import Callable, Mapping, Protocol

import numpy as np
import torch
import trimesh
from torch import Tensor

from mapping.model.field import FieldOutput
from mapping.model.observed import UNKNOWN, ObservedSpace


class QueryableField(Protocol):
    """What ``ObservedRows`` wraps: an ``InstanceFieldBank`` or a ``LiveRows`` view of one."""

    @property
    def num_instances(self) -> int: ...
    @property
    def bound_min(self) -> Tensor: ...
    @property
    def bound_max(self) -> Tensor: ...
    def query(self, points: Tensor, rows: Tensor, with_colour: bool = True, block_size: int = 4096) -> FieldOutput: ...


class ObservedRows:
    """``field`` with each row's occupancy zero outside its observed space's reach (rows without one: as is).

    Args:
        field: the bank or view queried.
        spaces: row number (in ``field``'s numbering) -> that instance's observed space.
    """

    def __init__(self, field: QueryableField, spaces: Mapping[int, ObservedSpace]):
        self.field, self.spaces = field, dict(spaces)

    @property
    def num_instances(self) -> int:
        return self.field.num_instances

    @property
    def bound_min(self) -> Tensor:
        return self.field.bound_min

    @property
    def bound_max(self) -> Tensor:
        return self.field.bound_max

    def query(self, points: Tensor, rows: Tensor, with_colour: bool = True, block_size: int = 4096) -> FieldOutput:
        """The field's output with occupancy zeroed where the row's instance never saw surface nearby (colour
        too: zeros when asked for, whatever the field gives there). The networks run only on the points inside
        the reach: the readers (observation, reward probes, rendered views) ask mostly about points outside it."""
        allowed = self.mask(points, rows)
        if bool(allowed.all()):
            return self.field.query(points, rows, with_colour=with_colour, block_size=block_size)
        occupancy = points.new_zeros(len(points))
        colour = points.new_zeros(len(points), 3) if with_colour else None
        if bool(allowed.any()):
            out = self.field.query(points[allowed], rows[allowed], with_colour=with_colour, block_size=block_size)
            occupancy[allowed] = out.occupancy
            if out.colour is None:
                colour = None
            elif colour is not None:
                colour[allowed] = out.colour
        return FieldOutput(occupancy, colour)

    def looked(self, points: Tensor, rows: Tensor) -> Tensor:
        """(n,) bool: the row's instance looked at the point's cell (True for rows without a space)."""
        return self.mask(points, rows, looked_grid)

    def mask(self, points: Tensor, rows: Tensor, grid_of: Callable[[ObservedSpace], np.ndarray] | None = None
             ) -> Tensor:
        """(n,) bool: ``grid_of(space)`` (default: the surface reach) at each point's cell of its row's space, False
        outside that grid, True for rows without a space. One gather over all rows: every row's grid laid end to
        end in one flat buffer (the per-row loop it replaces cost a tenth of an ``rl_small`` step)."""
        grid_of = ObservedSpace.surface_reach if grid_of is None else grid_of
        allowed = torch.ones(len(points), dtype=torch.bool, device=points.device)
        if not self.spaces or not len(points):
            return allowed
        present = [r for r in torch.unique(rows).tolist() if int(r) in self.spaces]
        if not present:
            return allowed
        spaces = [self.spaces[int(r)] for r in present]
        grids = [np.asarray(grid_of(sp), bool) for sp in spaces]
        device = points.device
        sizes = torch.as_tensor([g.size for g in grids], dtype=torch.long, device=device)
        cell_of = torch.as_tensor([sp.cell_m for sp in spaces], dtype=torch.float64, device=device)
        origin_of = torch.as_tensor(np.stack([sp.origin for sp in spaces]), dtype=torch.long, device=device)
        shape_of = torch.as_tensor([g.shape for g in grids], dtype=torch.long, device=device)
        offset_of = torch.cumsum(sizes, 0) - sizes  # where each grid starts in the flat buffer
        lookup = torch.full((int(rows.max()) + 1,), -1, dtype=torch.long, device=device)
        lookup[torch.as_tensor(present, dtype=torch.long, device=device)] = torch.arange(len(present), device=device)
        which = torch.where(rows >= 0, lookup[rows.clamp_min(0)], -1)  # a negative row has no space
        has_space = which >= 0
        k = which[has_space]
        # true division by the cell (as ObservedSpace.cells_of in NumPy) on every device; a Python-float divisor
        # would be a reciprocal multiply on CUDA, a cell apart at exact float64 boundaries
        idx = torch.floor(points[has_space].double() / cell_of[k, None]).long() - origin_of[k]
        shape = shape_of[k]
        inside = ((idx >= 0) & (idx < shape)).all(dim=1)
        flat = offset_of[k] + (idx[:, 0] * shape[:, 1] + idx[:, 1]) * shape[:, 2] + idx[:, 2]
        buffer = torch.as_tensor(np.concatenate([g.reshape(-1) for g in grids]), device=device)
        value = torch.zeros(len(idx), dtype=torch.bool, device=device)
        value[inside] = buffer[flat[inside]]
        allowed[has_space] = value
        return allowed


def looked_grid(space: ObservedSpace) -> np.ndarray:
    """(X, Y, Z) bool: some ray looked at the cell (free or surface)."""
    return space.states > UNKNOWN


def observed_faces(mesh: trimesh.Trimesh, space: ObservedSpace, allowed: np.ndarray | None = None
                   ) -> trimesh.Trimesh | None:
    """``mesh`` with only the faces whose centre lies in an ``allowed`` cell of ``space``'s grid (default: its
    surface reach); None when none is left.

    Faces are cut rather than the occupancy zeroed before marching cubes: a zeroed unknown interior would
    close every object with a second, invented face a few cm behind the surface it saw."""
    allowed = space.surface_reach() if allowed is None else allowed
    idx = space.cells_of(np.asarray(mesh.triangles_center)) - space.origin
    inside = np.all((idx >= 0) & (idx < np.array(allowed.shape)), axis=1)
    keep = np.zeros(len(idx), bool)
    keep[inside] = allowed[tuple(idx[inside].T)]
    if keep.all():
        return mesh
    if not keep.any():
        return None
    out = mesh.copy()
    out.update_faces(keep)
    out.remove_unreferenced_vertices()
    return out


class ReachSamples:
    """``extract_instance_mesh``'s ``needed`` for ``observed_faces``: which samples of a meshing grid lie within
    a margin (per axis) of a cell of ``space``'s surface reach, the only places whose faces are kept.

    The box of half-side ``margin`` around a sample meets, per axis, the cells from that of ``x - margin`` to
    that of ``x + margin``; the box meets a reach cell when the reach, OR-ed over those ranges axis by axis
    (the box is a product of intervals), is true. Cells outside the space's grid are not reach."""

    SLACK_M = 1e-6
    """Added to the margin: face centres are float sums of vertices on the cube's edges, and the grid samples
    are float32 (rounding ~1e-7 m at room scale)."""

    def __init__(self, space: ObservedSpace):
        self.space = space

    def __call__(self, origin: np.ndarray, voxel_m: float, shape: tuple[int, int, int]) -> np.ndarray:
        """(X, Y, Z) bool over the grid of samples ``origin + voxel_m * (i, j, k)``, margin one voxel."""
        reach = self.space.surface_reach()
        if not reach.size or not reach.any():
            return np.zeros(shape, bool)
        margin, cell = voxel_m + self.SLACK_M, self.space.cell_m
        out = np.pad(reach, 1, constant_values=False)  # index 0 and -1: every cell outside the grid
        for axis in range(3):
            coords = origin[axis] + voxel_m * np.arange(shape[axis])
            first = np.floor((coords - margin) / cell).astype(np.int64) - self.space.origin[axis] + 1
            last = np.floor((coords + margin) / cell).astype(np.int64) - self.space.origin[axis] + 1
            first, last = np.clip(first, 0, out.shape[axis] - 1), np.clip(last, 0, out.shape[axis] - 1)
            ored = np.zeros(out.shape[:axis] + (shape[axis],) + out.shape[axis + 1:], bool)
            for step in range(int((last - first).max()) + 1):
                ored |= np.take(out, np.minimum(first + step, last), axis=axis)
            out = ored
        return out
