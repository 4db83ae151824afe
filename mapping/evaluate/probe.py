"""A cheap completion-ratio estimate: probe the fields along the normals of ground-truth surface samples.

Completion ratio (sec. IV) is the share of ground-truth surface points within 5 cm of the
reconstructed mesh, which needs marching cubes of every instance (seconds per agent). The mesh of an
instance is the 0.5 level set of its occupancy inside its box, zero outside (``extract_instance_mesh``
pads with zeros). So a ground-truth point p with normal n has the surface near it when some instance's
occupancy crosses 0.5 on the segment p + t n, |t| <= 5 cm, with points outside that instance's box
counted as empty, and so are points away from the surface the instance observed (``observed_field``,
as its mesh keeps only faces there). This reads a handful of field values per point instead of meshing; the env measures
how closely it tracks the mesh-based figure (``benchmarks/bench_env.py``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

DEFAULT_OFFSETS_M = (-0.05, -0.03, -0.01, 0.01, 0.03, 0.05)
"""Where along the normal each point is probed: out to the 5 cm of the completion ratio, 2 cm apart
(a box's zero-padded face 5 cm away counts, as its mesh does; 11 probes 1 cm apart gave the same
coverage to 0.2 points on ``tiny``)."""


@torch.no_grad()
def surface_probe_coverage(mapper, points: np.ndarray, normals: np.ndarray,
                           offsets_m: Sequence[float] = DEFAULT_OFFSETS_M, level: float = 0.5) -> np.ndarray:
    """Which surface points the agent's map reproduces.

    Parameters
    ----------
    mapper : MappingAgent
      Its live instances (object and structure banks) are probed.
    points, normals : (P, 3) float
      Ground-truth surface samples and their unit normals.
    offsets_m : (K,) float
      Probe positions along each normal.

    Returns
    -------
    covered : (P,) bool
      True where some instance's occupancy crosses ``level`` on the probe segment.
    """
    covered = np.zeros(len(np.asarray(points)), bool)
    for _, point, crosses in _crossings(mapper, points, normals, offsets_m, level):
        covered[point[crosses]] = True
    return covered


@torch.no_grad()
def instance_probe_coverage(mapper, points: np.ndarray, normals: np.ndarray,
                            offsets_m: Sequence[float] = DEFAULT_OFFSETS_M, level: float = 0.5) -> dict[int, np.ndarray]:
    """Per live instance id, which surface points that instance alone reproduces: ``surface_probe_coverage`` is
    their union (a recorded episode replays each instance's share, ``mapping.team.recording``)."""
    out = {iid: np.zeros(len(np.asarray(points)), bool) for iid in mapper.live_ids()}
    for iids, point, crosses in _crossings(mapper, points, normals, offsets_m, level):
        for iid in np.unique(iids[crosses]):
            out[int(iid)][point[crosses & (iids == iid)]] = True
    return out


def _crossings(mapper, points: np.ndarray, normals: np.ndarray, offsets_m: Sequence[float], level: float):
    """Per bank: (instance id, point index, crosses) of every (instance, point) pair within the instance's box
    plus the probe reach, as NumPy arrays."""
    points = np.asarray(points, np.float32)
    normals = np.asarray(normals, np.float32)
    if points.ndim != 2 or points.shape[1] != 3 or normals.shape != points.shape:
        raise ValueError(f"points and normals must both be (P, 3), got {points.shape} and {normals.shape}")
    if len(points) == 0:
        return
    offsets = torch.as_tensor(list(offsets_m), dtype=torch.float32, device=mapper.device)
    reach = float(offsets.abs().max())
    p = torch.as_tensor(points, device=mapper.device)
    n = torch.as_tensor(normals, device=mapper.device)
    probes = p[:, None] + offsets[None, :, None] * n[:, None]  # (P, K, 3)
    for name, bank in mapper.banks.items():
        by_row = {s.row: iid for iid, s in mapper.slots.items() if s.bank == name and s.alive}
        rows = sorted(by_row)
        if not rows:
            continue
        rows_t = torch.as_tensor(rows, dtype=torch.long, device=mapper.device)
        lo, hi = bank.bound_min[rows_t], bank.bound_max[rows_t]  # (R, 3)
        near = ((p[None] >= lo[:, None] - reach) & (p[None] <= hi[:, None] + reach)).all(-1)  # (R, P)
        inst, point = torch.nonzero(near, as_tuple=True)
        if len(inst) == 0:
            continue
        pts = probes[point]  # (Q, K, 3)
        inside = ((pts >= lo[inst, None]) & (pts <= hi[inst, None])).all(-1)  # (Q, K)
        field = mapper.observed_field(name)  # zero where the instance never saw surface nearby
        occ = field.query(pts.reshape(-1, 3), rows_t[inst].repeat_interleave(len(offsets)), with_colour=False)
        occ = torch.where(inside, occ.occupancy.reshape(inside.shape), torch.zeros_like(inside, dtype=torch.float32))
        crosses = (occ.max(dim=1).values > level) & (occ.min(dim=1).values < level)
        ids = np.asarray([by_row[r] for r in rows], np.int64)[inst.cpu().numpy()]
        yield ids, point.cpu().numpy(), crosses.cpu().numpy()


def estimated_completion_ratio(covered: np.ndarray) -> float:
    """Share of probed points covered, in percent (the unit of ``comp_ratio``)."""
    return 100.0 * float(np.mean(covered)) if len(covered) else 0.0
