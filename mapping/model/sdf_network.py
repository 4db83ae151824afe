"""MACIM's scene network (iSDF's ``SDFMap``), evaluated for a bank of rows like the instance networks.

The published form of the global baselines (``mapping.team.global_map``, ``PUBLISHED``) maps a point
to a signed distance, not an occupancy. Read from ``BIT-DYN/MACIM`` (``mocim/modules/fc_map.py``,
``embedding.py``, ``train/configs/replicaCAD.json``)::

    t = (x - scene centre) * 0.0594              (metres scaled: ``SdfConfig.encoding_per_m``)
    encoding: a_j = d_j . t on the same 21 icosahedron axes as vMAP; sin(2^k a_j) and cos(2^k a_j)
              for k = 0..5, then t itself                              2*21*6 + 3 = 255 inputs (E)
    network:  E -> W, W -> W, W -> W, skip [h, encoding] (W+E) -> W, W -> W, W -> W, W -> 1,
              softplus(beta=100) after every hidden layer, W = 256
    sdf = 0.14 * output                          (``SdfConfig.scale_output``)

Xavier-normal weights and PyTorch's default biases, as theirs. Stored as one flat row per agent, so the
channel, eq. 12 and DiNNO treat it like any instance network; the skip layer's encoding rows ride beside
the first layer's in one (E, 2W) matmul, as ``mapping.model.instance_params`` does for vMAP's.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from mapping.model.encoding import N_BANDS, N_DIRECTIONS

SDF_ENCODING_DIM = 3 + 2 * N_DIRECTIONS * N_BANDS
"""E = 255: sine and cosine of 6 bands on 21 axes, and the scaled coordinates."""
SOFTPLUS_BETA = 100.0
"""iSDF's activation: softplus(beta=100), a smooth ReLU (an SDF's gradient must exist everywhere)."""


def sdf_param_layout(width: int) -> list[tuple[str, tuple[int, ...]]]:
    """Names and shapes of the network's parameters, in their order inside the flat row."""
    w, e = width, SDF_ENCODING_DIM
    return [
        ("w_enc", (e, 2 * w)),  # [first layer | skip layer's encoding rows]
        ("b_enc", (2 * w,)),  # [first layer bias | skip layer bias]
        ("w_mid1a", (w, w)), ("b_mid1a", (w,)),
        ("w_mid1b", (w, w)), ("b_mid1b", (w,)),
        ("w_skip", (w, w)),  # the skip layer's hidden rows
        ("w_mid2a", (w, w)), ("b_mid2a", (w,)),
        ("w_mid2b", (w, w)), ("b_mid2b", (w,)),
        ("w_out", (w, 1)), ("b_out", (1,)),
    ]


def sdf_flops_per_point(width: int) -> int:
    """Forward FLOPs of one point (2 * in * out over the layers; activations ignored)."""
    w, e = width, SDF_ENCODING_DIM
    return sum(2 * i * o for i, o in [(e, w), (w, w), (w, w), (w + e, w), (w, w), (w, w), (w, 1)])


def init_sdf_params(width: int, k: int, generator: torch.Generator | None = None) -> Tensor:
    """(k, D) float32 initial rows drawn on the CPU (Xavier-normal weights, uniform(+-1/sqrt(fan_in))
    biases); the skip layer is drawn whole and cut."""
    w, e = width, SDF_ENCODING_DIM

    def weight(fan_in: int, fan_out: int) -> Tensor:
        return torch.randn(k, fan_in, fan_out, generator=generator) * math.sqrt(2.0 / (fan_in + fan_out))

    def bias(fan_in: int, fan_out: int) -> Tensor:
        return (torch.rand(k, fan_out, generator=generator) * 2.0 - 1.0) / math.sqrt(fan_in)

    w_in, b_in = weight(e, w), bias(e, w)
    mid = {name: (weight(w, w), bias(w, w)) for name in ("mid1a", "mid1b")}
    w_skip, b_skip = weight(w + e, w), bias(w + e, w)  # rows: [hidden, encoding] as their cat
    mid |= {name: (weight(w, w), bias(w, w)) for name in ("mid2a", "mid2b")}
    w_out, b_out = weight(w, 1), bias(w, 1)
    parts = {"w_enc": torch.cat([w_in, w_skip[:, w:]], dim=2), "b_enc": torch.cat([b_in, b_skip], dim=1),
             "w_skip": w_skip[:, :w], "w_out": w_out, "b_out": b_out}
    for name, (wt, bs) in mid.items():
        parts[f"w_{name}"], parts[f"b_{name}"] = wt, bs
    return torch.cat([parts[name].reshape(k, -1) for name, _ in sdf_param_layout(width)], dim=1)


def sdf_encoding(scaled: Tensor, directions: Tensor) -> Tensor:
    """(..., P, E) encoding of (..., P, 3) scaled coordinates t: [t, sin(2^k d_j . t), cos(2^k d_j . t)]."""
    bands = 2.0 ** torch.arange(N_BANDS, dtype=scaled.dtype, device=scaled.device)
    phase = (scaled @ directions.to(scaled).T)[..., None] * bands  # (..., P, 21, 6)
    phase = phase.flatten(-2)
    return torch.cat([scaled, torch.sin(phase), torch.cos(phase)], dim=-1)


SOFTPLUS_FLOOR = -0.7
"""Below it softplus (beta 100) is under exp(-70) / 100 = 4e-33 and its slope under 4e-31: ``Softplus`` treats
every x below as this (values and gradients move by under 1e-30). Without the floor, exp and sigmoid make
denormal floats there, which this CPU computes about 10x slower (a training step took 11 s instead of 1 s)."""


class Softplus(torch.autograd.Function):
    """iSDF's softplus(beta=100), log(1 + exp(beta x)) / beta, with ``SOFTPLUS_FLOOR``, as one autograd node
    whose backward, g * sigmoid(beta x), is itself differentiable (the eikonal term differentiates it again).

    Why not ``F.softplus``: it goes through log1p, which ran 5-10x slower than log here (not vectorised), and
    composed of elementwise torch ops the double backward of a step took 3 s, 80 % of it elementwise
    passes; as one node a step is about 2x faster. ``log(1 + e)`` rounding off an e below 6e-8 moves the
    value by under 1e-9 m."""

    @staticmethod
    def forward(ctx, x: Tensor) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(x)
        e = torch.exp(x.abs().mul_(-SOFTPLUS_BETA).clamp_(min=SOFTPLUS_BETA * SOFTPLUS_FLOOR))
        return torch.relu(x).add_(e.add_(1.0).log_(), alpha=1.0 / SOFTPLUS_BETA)

    @staticmethod
    def backward(ctx, grad: Tensor) -> Tensor:  # type: ignore[override]
        (x,) = ctx.saved_tensors
        return grad * torch.sigmoid(x.clamp(min=SOFTPLUS_FLOOR) * SOFTPLUS_BETA)


def softplus(x: Tensor) -> Tensor:
    """iSDF's softplus(beta=100) (``Softplus``)."""
    return Softplus.apply(x)


def sdf_mlp(p: dict[str, Tensor], encoding: Tensor, width: int, scale_output: float) -> Tensor:
    """n scene networks, each on its own P points: (n, P, E) encodings -> (n, P) signed distances (metres).

    ``p``: per-layer views (n, *shape) of the n rows (``InstanceFieldBank.split_params``)."""
    b = {name: t.unsqueeze(1) for name, t in p.items() if name.startswith("b_")}  # (n, 1, out)
    act = softplus
    pre_in, pre_skip = torch.split(torch.baddbmm(b["b_enc"], encoding, p["w_enc"]), width, dim=-1)
    h = act(pre_in)
    h = act(torch.baddbmm(b["b_mid1a"], h, p["w_mid1a"]))
    h = act(torch.baddbmm(b["b_mid1b"], h, p["w_mid1b"]))
    h = act(torch.baddbmm(pre_skip, h, p["w_skip"]))  # skip layer (W+E -> W)
    h = act(torch.baddbmm(b["b_mid2a"], h, p["w_mid2a"]))
    h = act(torch.baddbmm(b["b_mid2b"], h, p["w_mid2b"]))
    return torch.baddbmm(b["b_out"], h, p["w_out"]).squeeze(-1) * scale_output
