"""The instance network (paper eq. 5, vMAP's ``OccupancyMap``) evaluated for many instances at once.

Network, hidden width W (32 for objects, 128 for structure: walls, floor, ceiling)::

    x (world) -> u in [-1, 1]^3 (the instance's frame) -> t = u / encoding_scale
    encoding: a_j = d_j . t on 21 fixed directions d_j; sin(pi 2^k a_j) for k = 0..5 (sin only, as
              vMAP's UniDirsEmbed); geometry input = [bands 0-3, t]   4*21 + 3 = 87
                                    colour extra   = bands 4-5         2*21     = 42
    geometry: 87 -> W, W -> W, skip [h, geometry input] (W+87) -> W, W -> W, W -> 1 (ReLU between)
    colour:   [h, colour extra] (W+42) -> W -> 3, sigmoid
    occupancy o = sigmoid(10 * raw)

Why stacked ``bmm``/``baddbmm`` and not ``torch.func.functional_call`` + ``vmap``: vmap lowers each
Linear to the same batched matmuls plus its own batching overhead, and cannot merge layers; on this
2-core CPU its forward + backward took 1.15-1.4x as long as the hand-batched form, and a Python loop
over instances (one module and one AdamW each) 1.2-18x as long as the whole batched step
(``benchmarks/bench_field.py`` measures all three). The layers are stored split and merged for speed
(see ``mapping.model.instance_params.param_layout``): the first layer and the skip layer's encoding rows
are one (87, 2W) matmul; the occupancy output rides as one extra column of the colour layer (a
1-column matmul runs at 2-3 GFLOP/s); and no gradient is computed for the encodings (vMAP's
concatenated skip and colour inputs would waste 12 % of the backward work on them).
"""

from __future__ import annotations

import torch
from torch import Tensor

LOGIT_LIMIT = 30.0
"""Occupancy logits are clamped to +-30: beyond, o is 1 or < 1e-13 in float32 anyway, and the sigmoid's
gradient would underflow into denormal floats (slow on many CPUs) that then spread through backward."""


def occupancy_logit(raw: Tensor, sharpness: float) -> Tensor:
    """sharpness * raw, clamped to +-LOGIT_LIMIT."""
    return (sharpness * raw).clamp(-LOGIT_LIMIT, LOGIT_LIMIT)


def batched_mlp(p: dict[str, Tensor], geometry: Tensor, colour_in: Tensor, width: int, sharpness: float,
                with_colour: bool, logits: bool = False) -> tuple[Tensor, Tensor | None]:
    """n instance networks, each on its own P points, as one batched computation.

    Args:
        p: per-layer views (n, *shape) of the n rows (``InstanceFieldBank.split_params``).
        geometry, colour_in: (n, P, 87) and (n, P, 42) encodings (``mapping.model.encoding.encode_positions``).
        width: W, the hidden width.
        sharpness: ``FieldConfig.occupancy_sharpness``.
        with_colour: skip the colour head when False.
        logits: return the clamped occupancy logit instead of the occupancy.

    Returns:
        occupancy (or its logit) (n, P) and colour (n, P, 3) (None without colour).
    """
    w = width
    b = {name: t.unsqueeze(1) for name, t in p.items() if name.startswith("b_")}  # (n, 1, out)
    # torch.split (one backward concatenation), not slicing (a zero-filled gradient per slice).
    pre_in, pre_skip = torch.split(torch.baddbmm(b["b_enc"], geometry, p["w_enc"]), w, dim=-1)
    h = torch.relu(pre_in)
    h = torch.relu_(torch.baddbmm(b["b_mid1"], h, p["w_mid1"]))
    h = torch.relu_(torch.baddbmm(pre_skip, h, p["w_skip"]))  # skip layer (W+87 -> W)
    h = torch.relu_(torch.baddbmm(b["b_mid2"], h, p["w_mid2"]))
    pre_col, raw = torch.split(torch.baddbmm(b["b_head"], h, p["w_head"]), w, dim=-1)  # colour part | raw
    logit = occupancy_logit(raw.squeeze(-1), sharpness)
    occupancy = logit if logits else torch.sigmoid(logit)
    if not with_colour:
        return occupancy, None
    c = torch.relu_(torch.baddbmm(pre_col, colour_in, p["w_col_enc"]))  # colour layer (W+42 -> W)
    return occupancy, torch.sigmoid(torch.baddbmm(b["b_rgb"], c, p["w_rgb"]))
