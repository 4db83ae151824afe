"""vMAP's directional sine encoding of box coordinates, the input of every instance network.

A point t (box coordinates, divided by the encoding scale) is projected on 21 fixed directions d_j
(the icosahedron's axes) and encoded as sin(pi 2^k d_j . t) for k = 0..5 (sin only, as vMAP's
``UniDirsEmbed``). Bands 0-3 and t itself feed the geometry trunk (4*21 + 3 = 87 inputs), bands 4-5
only the colour head (2*21 = 42 inputs).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

N_DIRECTIONS = 21
N_BANDS = 6  # frequencies 2^0 .. 2^5 (vMAP: n_unidir_funcs = 5)
GEOMETRY_BANDS = 4  # the first four feed the geometry trunk, the last two only the colour head
GEOMETRY_INPUT_DIM = 3 + GEOMETRY_BANDS * N_DIRECTIONS  # 87
COLOUR_INPUT_DIM = (N_BANDS - GEOMETRY_BANDS) * N_DIRECTIONS  # 42


def icosahedron_directions() -> Tensor:
    """(21, 3) float32 unit vectors: the 6 vertex axes and 15 edge-midpoint axes of a regular icosahedron.

    The same well-spread set as vMAP's fixed projection table, derived here instead of tabulated; each
    axis once (an antipode only flips the sign of the sine), sorted for a stable order.
    """
    phi = (1.0 + 5.0**0.5) / 2.0
    verts = []
    for a in (-1.0, 1.0):
        for b in (-phi, phi):
            verts += [(0.0, a, b), (a, b, 0.0), (b, 0.0, a)]
    v = torch.tensor(verts, dtype=torch.float64)  # 12 vertices, edge length 2
    i, j = torch.triu_indices(12, 12, offset=1)
    is_edge = ((v[i] - v[j]).norm(dim=1) - 2.0).abs() < 1e-9
    dirs = torch.cat([v, (v[i[is_edge]] + v[j[is_edge]]) / 2.0])
    dirs = dirs / dirs.norm(dim=1, keepdim=True)
    first = dirs[torch.arange(len(dirs)), (dirs.abs() > 1e-9).to(torch.int64).argmax(dim=1)]
    dirs = dirs * first.sign()[:, None]  # one representative per axis: first non-zero component > 0
    dirs = torch.unique(dirs.round(decimals=6), dim=0)
    assert dirs.shape == (N_DIRECTIONS, 3)
    return dirs.float()


def encode_positions(unit_coords: Tensor, directions: Tensor, scale: float, with_colour: bool = True
                     ) -> tuple[Tensor, Tensor | None]:
    """vMAP's directional sine encoding, split into the geometry input and the colour-only extra.

    Speed on CPU (measured 1.7x faster than the direct form): sin(2^k a) for k >= 1 comes from sin a
    and cos a by the double-angle recursion (one multiply and one fused multiply-add per band instead
    of a sine of a large argument; no less accurate, since the float32 argument 2^5 pi a itself
    carries ~1e-5 error), and the features are written feature-major into one (..., 129, P) buffer,
    so every elementwise pass runs over long contiguous rows; the outputs are transposed views of it,
    which the matmuls read at no cost.

    Args:
        unit_coords: (..., P, 3) box coordinates (inside the box in [-1, 1]).
        directions: (21, 3) unit projection directions.
        scale: coordinates are divided by it first (vMAP: obj_scale).
        with_colour: False skips bands 4-5 (meshing and depth-only rendering read no colour; the geometry
            input is the same, bit for bit, in the same buffer layout).

    Returns:
        (..., P, 87) geometry input [sin bands 0-3, t] and (..., P, 42) colour extra [sin bands 4-5] (None
        without colour), where t = u / scale and band k is sin(pi 2^k d_j . t).
    """
    n_dir, n_col = N_DIRECTIONS, COLOUR_INPUT_DIM
    eye = torch.eye(3, dtype=unit_coords.dtype, device=unit_coords.device)
    projection = torch.cat([directions.to(unit_coords) * math.pi, eye]) / scale  # (24, 3): band-0 phases and t
    phase_t = projection @ unit_coords.transpose(-1, -2)  # (..., 24, P)
    features = unit_coords.new_empty(*phase_t.shape[:-2], n_col + GEOMETRY_INPUT_DIM, phase_t.shape[-1])
    features[..., -3:, :] = phase_t[..., n_dir:, :]
    rows = [n_col + k * n_dir for k in range(GEOMETRY_BANDS)] + [k * n_dir for k in range(N_BANDS - GEOMETRY_BANDS)]
    phase = phase_t[..., :n_dir, :]
    s = torch.sin(phase, out=features[..., rows[0] : rows[0] + n_dir, :])
    c2 = torch.cos(phase).mul_(2.0)  # 2 cos a
    two = torch.full((), 2.0, dtype=phase.dtype, device=phase.device)
    bands = N_BANDS if with_colour else GEOMETRY_BANDS
    for k in range(1, bands):
        s_next = torch.mul(s, c2, out=features[..., rows[k] : rows[k] + n_dir, :])  # sin 2a = sin a * 2 cos a
        if k + 1 < bands:
            c2 = torch.addcmul(two, s, s, value=-4.0)  # 2 cos 2a = 2 - 4 sin^2 a
        s = s_next
    colour = features[..., :n_col, :].transpose(-1, -2) if with_colour else None
    return features[..., n_col:, :].transpose(-1, -2), colour
