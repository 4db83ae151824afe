"""Meshes from instance fields: marching cubes on a bounded grid, scene merge, PLY export.

vMAP meshes each object's occupancy field with marching cubes at level 0.5 on a regular grid over
the object's box (voxel about 0.5 cm, at most 256 samples per axis; OpenObj uses 128). Here the
grid is padded with one layer of zeros before marching cubes, so a surface cut by the box is closed
half a voxel outside the box instead of being left open.

All coordinates are world metres.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import torch
import trimesh
from skimage.measure import marching_cubes

__all__ = [
    "INSTANCE_ID_PROPERTY",
    "colour_vertices",
    "export_scene_mesh",
    "extract_instance_mesh",
    "grid_for_bound",
    "instance_color",
    "load_scene_mesh",
    "merge_instance_meshes",
]

OccupancyFn = Callable[[torch.Tensor], torch.Tensor]
ColorFn = Callable[[torch.Tensor], torch.Tensor]
NeededFn = Callable[[np.ndarray, float, tuple[int, int, int]], np.ndarray]
"""``(origin, voxel_m, shape) -> (X, Y, Z) bool`` over the grid ``origin + voxel_m * (i, j, k)``: the samples
within one voxel (per axis) of where faces are kept; see ``extract_instance_mesh``'s ``needed``."""

INSTANCE_ID_PROPERTY = "instance_id"
"""Name of the per-vertex PLY property holding the instance id."""

# Tolerances, each with its reason.
_MIN_EXTENT_M = 1e-6
"""A box thinner than this on any axis has no interior to mesh (vMAP's boxes are >= 0.10 m)."""


def _as_numpy(x: object, dtype: type = np.float64) -> np.ndarray:
    """Convert a tensor or array-like to a NumPy array (tensors are detached and moved to CPU)."""
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=dtype)


def grid_for_bound(
    bound_min: object,
    bound_max: object,
    voxel_size_m: float = 0.01,
    max_resolution: int = 256,
) -> tuple[np.ndarray, float, tuple[int, int, int]]:
    """The regular grid that covers an axis-aligned box.

    The voxel is cubic. It is `voxel_size_m` unless the longest side would then need more than
    `max_resolution` samples, in which case it grows to `longest_side / (max_resolution - 1)`.

    Parameters
    ----------
    bound_min, bound_max : (3,) float
      Corners of the box, metres.
    voxel_size_m : float
      Requested voxel edge, metres.
    max_resolution : int
      Most samples along any axis (>= 2).

    Returns
    -------
    origin : (3,) float64
      World position of sample (0, 0, 0), equal to `bound_min`.
    voxel_m : float
      Voxel edge actually used, metres.
    shape : (3,) int
      Samples per axis; sample (i, j, k) sits at `origin + voxel_m * (i, j, k)` and the last
      sample on each axis is at or beyond `bound_max`.
    """
    lo = _as_numpy(bound_min).reshape(-1)
    hi = _as_numpy(bound_max).reshape(-1)
    if lo.shape != (3,) or hi.shape != (3,):
        raise ValueError(f"bounds must be 3-vectors, got shapes {lo.shape} and {hi.shape}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError(f"bounds must be finite, got {lo} and {hi}")
    extent = hi - lo
    if np.any(extent < _MIN_EXTENT_M):
        raise ValueError(f"bound_max must exceed bound_min on every axis, got extent {extent}")
    if not voxel_size_m > 0:
        raise ValueError(f"voxel_size_m must be positive, got {voxel_size_m}")
    if int(max_resolution) < 2:
        raise ValueError(f"max_resolution must be at least 2, got {max_resolution}")

    voxel_m = max(float(voxel_size_m), float(extent.max()) / (int(max_resolution) - 1))
    counts = np.ceil(extent / voxel_m - 1e-9).astype(np.int64) + 1  # 1e-9: float noise at exact fits
    counts = np.clip(counts, 2, int(max_resolution))
    return lo, voxel_m, (int(counts[0]), int(counts[1]), int(counts[2]))


def _grid_points(
    origin: np.ndarray, voxel_m: float, shape: tuple[int, int, int], start: int, stop: int,
    device: torch.device,
) -> torch.Tensor:
    """World positions of grid samples with flat (C-order) indices in [start, stop); (n, 3) float32.

    Index arithmetic is done in NumPy: int64 division in torch on CPU is about 20x slower.
    """
    return _indexed_points(origin, voxel_m, shape, np.arange(start, stop, dtype=np.int64), device)


@torch.no_grad()
def _evaluate_in_batches(
    fn: Callable,
    make_batch: Callable[[int, int], torch.Tensor],
    n: int,
    width: int,
    batch_points: int,
    name: str,
) -> np.ndarray:
    """Call `fn(make_batch(start, stop))` on consecutive batches; (n, width) float32.

    Each output must hold `(stop - start) * width` values (e.g. (b,) or (b, 1) for width 1).
    """
    out = np.empty((n, width), dtype=np.float32)
    for start in range(0, n, batch_points):
        stop = min(start + batch_points, n)
        values = _as_numpy(fn(make_batch(start, stop)), dtype=np.float32)
        if values.size != (stop - start) * width:
            raise ValueError(
                f"{name} returned shape {values.shape} for {stop - start} points, expected width {width}"
            )
        out[start:stop] = values.reshape(stop - start, width)
    return out


def _evaluate_needed(occupancy_fn: OccupancyFn, needed: NeededFn, origin: np.ndarray, voxel_m: float,
                     shape: tuple[int, int, int], batch_points: int, device: torch.device) -> np.ndarray:
    """(n,) float32 grid values: ``occupancy_fn`` on the samples ``needed`` keeps, 0 elsewhere."""
    mask = np.asarray(needed(origin, voxel_m, shape), bool)
    if mask.shape != tuple(shape):
        raise ValueError(f"needed returned shape {mask.shape} for a grid of {tuple(shape)}")
    index = np.flatnonzero(mask)
    values = np.zeros(mask.size, np.float32)
    if len(index):
        def needed_batch(start: int, stop: int) -> torch.Tensor:
            return _indexed_points(origin, voxel_m, shape, index[start:stop], device)

        values[index] = _evaluate_in_batches(occupancy_fn, needed_batch, len(index), 1, batch_points,
                                             "occupancy_fn").reshape(-1)
    return values


def _indexed_points(origin: np.ndarray, voxel_m: float, shape: tuple[int, int, int], flat: np.ndarray,
                    device: torch.device) -> torch.Tensor:
    """World positions of the grid samples with flat (C-order) indices ``flat``; (n, 3) float32."""
    i, rest = np.divmod(flat, shape[1] * shape[2])
    j, k = np.divmod(rest, shape[2])
    points = origin + voxel_m * np.stack((i, j, k), axis=-1)  # (n, 3) float64
    return torch.from_numpy(points.astype(np.float32)).to(device)


def extract_instance_mesh(
    occupancy_fn: OccupancyFn,
    bound_min: object,
    bound_max: object,
    voxel_size_m: float = 0.01,
    max_resolution: int = 256,
    level: float = 0.5,
    batch_points: int = 65536,
    color_fn: ColorFn | None = None,
    device: torch.device | str = "cpu",
    needed: NeededFn | None = None,
) -> trimesh.Trimesh | None:
    """Mesh the `level` set of an occupancy field inside an axis-aligned box.

    Parameters
    ----------
    occupancy_fn : callable
      `(n, 3) float32 tensor of world points -> (n,) occupancy in [0, 1]`; called under
      `torch.no_grad()` with at most `batch_points` points at a time.
    bound_min, bound_max : (3,) float
      Corners of the box, metres.
    voxel_size_m, max_resolution : float, int
      Grid spacing and cap on samples per axis, see `grid_for_bound`.
    level : float
      Iso-level in (0, 1); 0.5 as in vMAP.
    batch_points : int
      Points per call to `occupancy_fn` / `color_fn`.
    color_fn : callable or None
      `(n, 3) float32 tensor -> (n, 3)` colour in [0, 1] (vMAP's sigmoid output), evaluated at
      the vertices; stored as uint8 RGBA in `mesh.visual.vertex_colors`.
    device : torch device
      Where the query points are created.
    needed : callable or None
      For a caller that keeps only some faces afterwards (``observed_faces``): ``needed(origin, voxel,
      shape)`` says which grid samples lie within one voxel (per axis) of a place where faces are kept. Only those
      are evaluated; the rest read as 0. A face lies inside a grid cube, and a cube lies within one voxel of
      each of its corners, so every face kept afterwards comes from a cube whose eight corners were all
      evaluated: the same faces as a full evaluation gives, for the cost of the kept region only.

    Returns
    -------
    mesh : trimesh.Trimesh or None
      World-space mesh, faces wound outward (positive volume when closed), or None when no grid
      sample reaches `level` (nothing occupied). A box that is occupied everywhere gives the
      closed surface half a voxel outside the box (the zero padding), not None.
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie in (0, 1) so the zero padding is outside, got {level}")
    if batch_points < 1:
        raise ValueError(f"batch_points must be positive, got {batch_points}")
    device = torch.device(device)
    origin, voxel_m, shape = grid_for_bound(bound_min, bound_max, voxel_size_m, max_resolution)
    n = shape[0] * shape[1] * shape[2]

    def grid_batch(start: int, stop: int) -> torch.Tensor:
        return _grid_points(origin, voxel_m, shape, start, stop, device)

    if needed is None:
        values = _evaluate_in_batches(occupancy_fn, grid_batch, n, 1, batch_points, "occupancy_fn").reshape(-1)
    else:
        values = _evaluate_needed(occupancy_fn, needed, origin, voxel_m, shape, batch_points, device)
    if not np.all(np.isfinite(values)):
        raise ValueError(f"occupancy_fn returned {np.count_nonzero(~np.isfinite(values))} non-finite values")
    if not values.max() > level:
        return None

    # One layer of zeros on every side closes surfaces that the box cuts.
    grid = np.pad(values.reshape(shape), 1, mode="constant", constant_values=0.0)
    # Occupancy is high inside: 'ascent' winds faces so normals point from inside to outside.
    verts, faces, _, _ = marching_cubes(grid, level=level, spacing=(voxel_m,) * 3, gradient_direction="ascent")
    verts = verts.astype(np.float64) + (origin - voxel_m)  # padded index 0 sits one voxel below origin
    mesh = trimesh.Trimesh(vertices=verts, faces=faces, process=False)

    if color_fn is not None:
        colour_vertices(mesh, color_fn, batch_points, device)
    return mesh


def colour_vertices(mesh: trimesh.Trimesh, color_fn: ColorFn, batch_points: int = 65536,
                    device: torch.device | str = "cpu") -> trimesh.Trimesh:
    """Set ``mesh``'s vertex colours (uint8 RGBA) from ``color_fn`` at its vertices, in place; returns it.

    Separate from ``extract_instance_mesh`` so a caller that cuts faces afterwards colours only the vertices
    it keeps (the colour head costs as much per point as the occupancy)."""
    vert_t = torch.as_tensor(np.asarray(mesh.vertices), dtype=torch.float32, device=torch.device(device))

    def vertex_batch(start: int, stop: int) -> torch.Tensor:
        return vert_t[start:stop]

    colors = _evaluate_in_batches(color_fn, vertex_batch, len(vert_t), 3, batch_points, "color_fn")
    mesh.visual.vertex_colors = _to_rgba_uint8(colors)
    return mesh


def _to_rgba_uint8(colors: np.ndarray) -> np.ndarray:
    """(n, 3) colours in [0, 1] to (n, 4) uint8 RGBA (values outside [0, 1] are clipped)."""
    rgba = np.full((len(colors), 4), 255, dtype=np.uint8)
    rgba[:, :3] = np.round(np.clip(colors, 0.0, 1.0) * 255.0).astype(np.uint8)
    return rgba


def instance_color(instance_id: int) -> np.ndarray:
    """A fixed, well-spread RGBA colour for an instance id; (4,) uint8 (golden-ratio hue walk)."""
    hue = (int(instance_id) * 0.6180339887498949) % 1.0
    rgb = np.clip(np.abs(((hue * 6.0 + np.array([0.0, 4.0, 2.0])) % 6.0) - 3.0) - 1.0, 0.0, 1.0)
    rgb = 0.25 + 0.7 * rgb  # avoid pure black/white so shading stays readable
    return np.append(np.round(rgb * 255.0), 255).astype(np.uint8)


def merge_instance_meshes(
    meshes: Mapping[int, trimesh.Trimesh | None],
) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Concatenate per-instance meshes into one scene mesh that remembers who owns each vertex.

    Parameters
    ----------
    meshes : {instance_id: trimesh.Trimesh or None}
      None or face-less entries are skipped. Instances are stacked in ascending id order.

    Returns
    -------
    scene : trimesh.Trimesh
      All vertices and faces (faces re-indexed), vertex colours kept where an instance has them
      and `instance_color(id)` otherwise; the ids are also in
      `scene.vertex_attributes[INSTANCE_ID_PROPERTY]`.
    vertex_instance_ids : (n_vertices,) int32
    """
    vertices, faces, colors, ids = [], [], [], []
    offset = 0
    for instance_id in sorted(meshes):
        mesh = meshes[instance_id]
        if mesh is None or len(mesh.faces) == 0:
            continue
        n = len(mesh.vertices)
        vertices.append(np.asarray(mesh.vertices, dtype=np.float64))
        faces.append(np.asarray(mesh.faces, dtype=np.int64) + offset)
        if mesh.visual.kind == "vertex" and len(mesh.visual.vertex_colors) == n:
            colors.append(np.asarray(mesh.visual.vertex_colors, dtype=np.uint8))
        else:
            colors.append(np.tile(instance_color(instance_id), (n, 1)))
        ids.append(np.full(n, instance_id, dtype=np.int32))
        offset += n

    if not vertices:
        return trimesh.Trimesh(), np.zeros(0, dtype=np.int32)
    vertex_instance_ids = np.concatenate(ids)
    scene = trimesh.Trimesh(
        vertices=np.concatenate(vertices),
        faces=np.concatenate(faces),
        vertex_colors=np.concatenate(colors),
        process=False,
    )
    scene.vertex_attributes[INSTANCE_ID_PROPERTY] = vertex_instance_ids
    return scene, vertex_instance_ids


def export_scene_mesh(path: str | os.PathLike, mesh: trimesh.Trimesh, vertex_instance_ids: np.ndarray) -> Path:
    """Write a binary PLY with vertex colour and an int32 `instance_id` vertex property, atomically.

    The file is written to a temporary sibling and moved into place with `os.replace`, so a reader
    never sees half a file. Read it back with `load_scene_mesh`; generic viewers (MeshLab,
    CloudCompare) show `instance_id` as a scalar field, Open3D drops it.

    Parameters
    ----------
    path : path-like
      Destination `.ply`; parent folders are created.
    mesh : trimesh.Trimesh
      Scene mesh, e.g. from `merge_instance_meshes`.
    vertex_instance_ids : (n_vertices,) int
    """
    ids = np.asarray(vertex_instance_ids).reshape(-1)
    if ids.shape[0] != len(mesh.vertices):
        raise ValueError(f"{ids.shape[0]} instance ids for {len(mesh.vertices)} vertices")
    out = mesh.copy()
    out.vertex_attributes = {INSTANCE_ID_PROPERTY: ids.astype(np.int32)}
    data = trimesh.exchange.ply.export_ply(out, encoding="binary", include_attributes=True)

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def load_scene_mesh(path: str | os.PathLike) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Read a PLY written by `export_scene_mesh`.

    Returns
    -------
    mesh : trimesh.Trimesh
      Vertices in file order (no merging), with vertex colours.
    vertex_instance_ids : (n_vertices,) int32
      From the `instance_id` property; -1 everywhere if the file has none.
    """
    mesh = trimesh.load(Path(path), file_type="ply", process=False, force="mesh")
    raw = mesh.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    names = getattr(getattr(raw, "dtype", None), "names", None) or ()
    if isinstance(raw, dict):
        names = tuple(raw)
    if INSTANCE_ID_PROPERTY in names:
        ids = np.asarray(raw[INSTANCE_ID_PROPERTY]).reshape(-1).astype(np.int32)
    else:
        ids = np.full(len(mesh.vertices), -1, dtype=np.int32)
    mesh.vertex_attributes[INSTANCE_ID_PROPERTY] = ids
    return mesh, ids
