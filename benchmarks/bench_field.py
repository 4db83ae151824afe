"""Field benchmark: one training step (forward + backward + Adam) of N instance MLPs, batched vs looped.

Prints (a) the GFLOP/s of a 2048 x 2048 float32 matmul (the machine's dense ceiling); (b) the batched
bank (``InstanceFieldBank`` + ``StackedAdam``) at each N x P setting: step time, its split into
forward / backward / Adam, and the achieved GFLOP/s (MLP FLOPs: 2 * in * out per layer per point,
x3 for forward + backward) as a share of the matmul; (c) a Python loop over instances (separate vMAP
modules with an AdamW each, as vMAP without vmap; and ``mapping.model.field_reference.looped_forward``) and
the speed-up; plus torch.func ``vmap`` over stacked modules (forward + backward) for the design choice.

All variants of a setting, the matmul included, are timed in interleaved rounds (one call of each per
round, median over rounds), so a process that competes for the cores slows them alike; absolute
figures are still only meaningful on an otherwise idle machine (the load is printed).

Run: `.venv/bin/python benchmarks/bench_field.py [--threads 2] [--repeats 30] [--json runs/bench_field.json]`.

Figures: docs/world.md#the-mapper-mapping, docs/profile.md#the-learners-arithmetic
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Callable

import torch
from torch import nn

from mapping.model.encoding import COLOUR_INPUT_DIM, GEOMETRY_INPUT_DIM, encode_positions
from mapping.model.field import FieldConfig, InstanceFieldBank
from mapping.model.field_reference import looped_forward
from mapping.model.instance_params import mlp_flops_per_point
from mapping.model.optim import AdamConfig, StackedAdam

SETTINGS = [(32, 20, 1200), (32, 100, 120), (32, 20, 240), (128, 4, 1200)]  # (width, instances, points)
"""vMAP: 120 rays x 10 samples per object per step (1200 points), 1200 rays for the background (W=128)."""


def interleaved_medians(fns: dict[str, Callable[[], object]], repeats: int, warmup: int = 3) -> dict[str, float]:
    """Median seconds of each function, timed in ``repeats`` rounds of one call each."""
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(t) for name, t in times.items()}


class VMapMLP(nn.Module):
    """vMAP's OccupancyMap as written there (concatenating skip and colour layers), for the loop baseline."""

    def __init__(self, width: int):
        super().__init__()
        g, c = GEOMETRY_INPUT_DIM, COLOUR_INPUT_DIM
        self.layers = nn.ModuleList([nn.Linear(g, width), nn.Linear(width, width), nn.Linear(width + g, width),
                                     nn.Linear(width, width), nn.Linear(width, 1), nn.Linear(width + c, width),
                                     nn.Linear(width, 3)])

    def forward(self, geometry: torch.Tensor, colour_in: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        l = self.layers
        h = torch.relu(l[1](torch.relu(l[0](geometry))))
        h = torch.relu(l[3](torch.relu(l[2](torch.cat([h, geometry], -1)))))
        occupancy = torch.sigmoid(10.0 * l[4](h))[..., 0]
        colour = torch.sigmoid(l[6](torch.relu(l[5](torch.cat([h, colour_in], -1)))))
        return occupancy, colour


def bench_setting(width: int, n: int, p: int, repeats: int) -> dict:
    bank = InstanceFieldBank(FieldConfig(hidden_width=width), device="cpu")
    g = torch.Generator().manual_seed(0)
    centres = torch.rand(n, 3, generator=g) * 4.0
    bank.add_instances(n, centres - 0.5, centres + 0.5, generator=g)
    opt = StackedAdam(bank, AdamConfig())
    points = bank.bound_min[:, None] + torch.rand(n, p, 3, generator=g) * (bank.bound_max - bank.bound_min)[:, None]
    target_occ, target_rgb = torch.rand(n, p, generator=g), torch.rand(n, p, 3, generator=g)

    def loss_of(occupancy: torch.Tensor, colour: torch.Tensor) -> torch.Tensor:
        return (occupancy - target_occ).abs().mean() + (colour - target_rgb).abs().mean()

    def batched_step() -> None:
        opt.zero_grad()
        loss_of(*bank(points)).backward()
        opt.step()

    def forward_only() -> None:
        with torch.no_grad():
            loss_of(*bank(points))

    def forward_backward() -> None:
        opt.zero_grad()
        loss_of(*bank(points)).backward()

    def looped_bank_step() -> None:
        opt.zero_grad()
        loss_of(*looped_forward(bank, points)).backward()
        opt.step()

    # vMAP without vmap: one module and one AdamW per instance, a Python loop over them.
    with torch.no_grad():
        geometry, colour_in = encode_positions(bank.to_unit(points), bank.directions, bank.config.encoding_scale)
        geometry, colour_in = geometry.contiguous(), colour_in.contiguous()
    modules = [VMapMLP(width) for _ in range(n)]
    optimisers = [torch.optim.AdamW(m.parameters(), lr=1e-3, weight_decay=0.013) for m in modules]

    def module_loop_step() -> None:
        for i, (module, optimiser) in enumerate(zip(modules, optimisers)):
            optimiser.zero_grad(set_to_none=True)
            occupancy, colour = module(geometry[i], colour_in[i])
            ((occupancy - target_occ[i]).abs().mean() + (colour - target_rgb[i]).abs().mean()).backward()
            optimiser.step()

    # torch.func: the same modules stacked, functional_call under vmap (forward + backward only).
    stacked, buffers = torch.func.stack_module_state(modules)
    base = VMapMLP(width).to("meta")
    vmapped = torch.func.vmap(lambda prm, buf, x, c: torch.func.functional_call(base, (prm, buf), (x, c)))

    def vmap_forward_backward() -> None:
        for t in stacked.values():
            t.grad = None
        loss_of(*vmapped(stacked, buffers, geometry, colour_in)).backward()

    a, b = torch.randn(2048, 2048), torch.randn(2048, 2048)
    fns = {"matmul": lambda: a @ b, "batched": batched_step, "forward": forward_only, "fwd_bwd": forward_backward,
           "adam": opt.step, "loop": module_loop_step, "looped_forward": looped_bank_step,
           "vmap_fwd_bwd": vmap_forward_backward}
    t = interleaved_medians(fns, repeats)
    matmul_gflops = 2 * 2048**3 / t["matmul"] / 1e9
    gflops = 3 * mlp_flops_per_point(width) * n * p / t["batched"] / 1e9
    return {"width": width, "instances": n, "points": p, "matmul_gflops": matmul_gflops,
            "batched_ms": t["batched"] * 1e3, "forward_ms": t["forward"] * 1e3,
            "backward_ms": (t["fwd_bwd"] - t["forward"]) * 1e3, "adam_ms": t["adam"] * 1e3,
            "batched_gflops": gflops, "of_matmul": gflops / matmul_gflops,
            "loop_modules_ms": t["loop"] * 1e3, "speedup_vs_loop": t["loop"] / t["batched"],
            "looped_forward_ms": t["looped_forward"] * 1e3, "speedup_vs_looped_forward": t["looped_forward"] / t["batched"],
            "vmap_fwd_bwd_ms": t["vmap_fwd_bwd"] * 1e3, "bank_fwd_bwd_ms": t["fwd_bwd"] * 1e3}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--keep-denormals", action="store_true", help="do not flush denormal floats to zero")
    parser.add_argument("--json", default=None, help="also write the figures to this JSON file")
    args = parser.parse_args()
    # Before the first parallel op: OpenMP worker threads only inherit the flag from the start.
    flush = False if args.keep_denormals else torch.set_flush_denormal(True)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads, flush denormals {flush}, load average {os.getloadavg()[0]:.2f}")
    print("step = forward + backward + Adam; MLP FLOPs = 2*in*out per layer per point, x3 for forward + backward")
    print(f"{'W':>3} {'N x P':>10} {'matmul':>7} | {'step':>6} {'fwd':>5} {'bwd':>5} {'adam':>5} {'GFLOP/s':>7} "
          f"{'of mm':>5} | {'loop':>7} {'x':>5} | {'looped':>7} {'x':>5} | {'vmap fb':>7} {'bank fb':>7}")
    rows = []
    for width, n, p in SETTINGS:
        r = bench_setting(width, n, p, args.repeats)
        rows.append(r)
        print(f"{width:>3} {n:>4} x {p:<4} {r['matmul_gflops']:>7.1f} | {r['batched_ms']:>6.1f} {r['forward_ms']:>5.1f} "
              f"{r['backward_ms']:>5.1f} {r['adam_ms']:>5.2f} {r['batched_gflops']:>7.1f} {100 * r['of_matmul']:>4.0f}% | "
              f"{r['loop_modules_ms']:>7.1f} {r['speedup_vs_loop']:>5.2f} | {r['looped_forward_ms']:>7.1f} "
              f"{r['speedup_vs_looped_forward']:>5.2f} | {r['vmap_fwd_bwd_ms']:>7.1f} {r['bank_fwd_bwd_ms']:>7.1f}")
    print("(times in ms; matmul = 2048^2 float32 GFLOP/s timed alongside; loop = one module + AdamW per instance;")
    print(" looped = looped_forward (mapping.model.field_reference) + StackedAdam; x = its time / the batched step; fb = forward + backward)")
    print("targets: batched >= 40% of the matmul; >= 2x faster than the loop at 100 x 120; not slower at 20 x 1200")
    print(f"load average after: {os.getloadavg()[0]:.2f} (well above 0 means another process shared the cores)")
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"threads": args.threads, "flush_denormals": flush, "rows": rows}, indent=2))
        os.replace(tmp, path)


if __name__ == "__main__":
    main()
