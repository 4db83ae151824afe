"""Layout of one instance network's parameters as a flat row, its initialisation and its cost.

Why one flat row per instance: a bank holds N instances as one (N, D) parameter, so sending an
instance between agents, the parameter-consistency loss (eq. 12) and DiNNO/DSGD mixing are row
operations, growth is a row concatenation, and Adam is one fused pass (``mapping.model.field``).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from mapping.model.encoding import COLOUR_INPUT_DIM, GEOMETRY_INPUT_DIM


def param_layout(width: int) -> list[tuple[str, tuple[int, ...]]]:
    """Names and shapes of one instance's parameters, in their order inside the flat row.

    vMAP's layers are stored split and merged for speed: the skip layer (W+87 -> W) is ``w_skip``
    (its hidden rows) plus the right half of ``w_enc`` (its encoding rows, beside the first layer's
    87 -> W); the colour layer (W+42 -> W) is the left part of ``w_head`` (hidden rows) plus
    ``w_col_enc``; the occupancy output (W -> 1) is the last column of ``w_head``.
    """
    w, g, c = width, GEOMETRY_INPUT_DIM, COLOUR_INPUT_DIM
    return [
        ("w_enc", (g, 2 * w)),  # [first layer | skip layer's encoding rows]
        ("b_enc", (2 * w,)),  # [first layer bias | skip layer bias]
        ("w_mid1", (w, w)),
        ("b_mid1", (w,)),
        ("w_skip", (w, w)),
        ("w_mid2", (w, w)),
        ("b_mid2", (w,)),
        ("w_head", (w, w + 1)),  # [colour layer's hidden rows | occupancy output]
        ("b_head", (w + 1,)),
        ("w_col_enc", (c, w)),
        ("w_rgb", (w, 3)),
        ("b_rgb", (3,)),
    ]


def mlp_flops_per_point(width: int) -> int:
    """Forward FLOPs of one point, 2 * in * out summed over the vMAP layers (biases and activations ignored)."""
    w, g, c = width, GEOMETRY_INPUT_DIM, COLOUR_INPUT_DIM
    layers = [(g, w), (w, w), (w + g, w), (w, w), (w, 1), (w + c, w), (w, 3)]
    return sum(2 * i * o for i, o in layers)


def init_instance_params(width: int, k: int, generator: torch.Generator | None = None) -> Tensor:
    """(k, D) float32 initial rows, drawn on the CPU so a seed gives the same network on any device.

    vMAP's init: Xavier-normal weights, PyTorch's default uniform(+-1/sqrt(fan_in)) biases; split
    layers are drawn whole (their fan-in includes both halves) and then cut.
    """
    g, c = GEOMETRY_INPUT_DIM, COLOUR_INPUT_DIM

    def weight(fan_in: int, fan_out: int) -> Tensor:
        std = math.sqrt(2.0 / (fan_in + fan_out))
        return torch.randn(k, fan_in, fan_out, generator=generator) * std

    def bias(fan_in: int, fan_out: int) -> Tensor:
        return (torch.rand(k, fan_out, generator=generator) * 2.0 - 1.0) / math.sqrt(fan_in)

    w = width
    w_in, b_in = weight(g, w), bias(g, w)
    w_mid1, b_mid1 = weight(w, w), bias(w, w)
    w_skip, b_skip = weight(w + g, w), bias(w + g, w)  # rows: [hidden, encoding] as vMAP's cat
    w_mid2, b_mid2 = weight(w, w), bias(w, w)
    w_occ, b_occ = weight(w, 1), bias(w, 1)
    w_col, b_col = weight(w + c, w), bias(w + c, w)
    w_rgb, b_rgb = weight(w, 3), bias(w, 3)
    parts = {
        "w_enc": torch.cat([w_in, w_skip[:, w:]], dim=2), "b_enc": torch.cat([b_in, b_skip], dim=1),
        "w_mid1": w_mid1, "b_mid1": b_mid1, "w_skip": w_skip[:, :w], "w_mid2": w_mid2, "b_mid2": b_mid2,
        "w_head": torch.cat([w_col[:, :w], w_occ], dim=2), "b_head": torch.cat([b_col, b_occ], dim=1),
        "w_col_enc": w_col[:, w:], "w_rgb": w_rgb, "b_rgb": b_rgb,
    }
    return torch.cat([parts[name].reshape(k, -1) for name, _ in param_layout(width)], dim=1)
