"""Field benchmark: one training step (forward + backward + Adam) of N instance MLPs, batched vs looped.

Prints (a) the GFLOP/s of a 2048 x 2048 float32 matmul (the machine's dense ceiling); (b) the batched
bank (``InstanceFieldBank`` + ``StackedAdam``) at each N x P setting: step time, its split into
forward / backward / Adam, and the achieved GFLOP/s (MLP FLOPs: 2 * in * out per layer per point,
x3 for forward + backward) as a share of the matmul; (c) a Python loop over instances (separate vMAP
modules with an AdamW each, as vMAP without vmap; and the bank's ``looped_forward``) and the speed-up.

Run: `.venv/bin/python benchmarks/bench_field.py [--threads 2] [--repeats 30] [--json runs/bench_field.json]`.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Callable

import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from mapping.field import (  # noqa: E402
    COLOUR_INPUT_DIM,
    GEOMETRY_INPUT_DIM,
    AdamConfig,
    FieldConfig,
    InstanceFieldBank,
    StackedAdam,
    encode_positions,
    icosahedron_directions,
    mlp_flops_per_point,
)

SETTINGS = [(20, 1200), (100, 120), (20, 240)]


def median_seconds(fn: Callable[[], object], repeats: int, warmup: int = 5) -> float:
    """Median wall time of ``fn`` over ``repeats`` calls after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def matmul_gflops(repeats: int) -> float:
    a, b = torch.randn(2048, 2048), torch.randn(2048, 2048)
    return 2 * 2048**3 / median_seconds(lambda: a @ b, repeats, warmup=3) / 1e9


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
        occupancy = torch.sigmoid(10.0 * l[4](h))[:, 0]
        colour = torch.sigmoid(l[6](torch.relu(l[5](torch.cat([h, colour_in], -1)))))
        return occupancy, colour


def make_bank(n: int, width: int, seed: int = 0) -> InstanceFieldBank:
    bank = InstanceFieldBank(FieldConfig(hidden_width=width), device="cpu")
    g = torch.Generator().manual_seed(seed)
    centres = torch.rand(n, 3, generator=g) * 4.0
    bank.add_instances(n, centres - 0.5, centres + 0.5, generator=g)
    return bank


def bench_setting(n: int, p: int, width: int, repeats: int) -> dict:
    bank = make_bank(n, width)
    opt = StackedAdam(bank, AdamConfig())
    g = torch.Generator().manual_seed(1)
    points = (bank.bound_min[:, None] + torch.rand(n, p, 3, generator=g) * (bank.bound_max - bank.bound_min)[:, None])
    target_occ, target_rgb = torch.rand(n, p, generator=g), torch.rand(n, p, 3, generator=g)

    def loss_of(occupancy: torch.Tensor, colour: torch.Tensor) -> torch.Tensor:
        return (occupancy - target_occ).abs().mean() + (colour - target_rgb).abs().mean()

    def batched_step() -> None:
        opt.zero_grad()
        loss_of(*bank(points)).backward()
        opt.step()

    def looped_bank_step() -> None:
        opt.zero_grad()
        loss_of(*bank.looped_forward(points)).backward()
        opt.step()

    # Forward / backward / Adam split of the batched step.
    def forward_only() -> torch.Tensor:
        return loss_of(*bank(points))

    def forward_backward() -> None:
        opt.zero_grad()
        forward_only().backward()

    t_batched = median_seconds(batched_step, repeats)
    t_fwd = median_seconds(forward_only, repeats)
    t_fwd_bwd = median_seconds(forward_backward, repeats)
    t_adam = median_seconds(opt.step, repeats)
    t_looped_bank = median_seconds(looped_bank_step, max(5, repeats // 3))

    # vMAP without vmap: one module and one AdamW per instance, a Python loop over them.
    directions = icosahedron_directions()
    with torch.no_grad():
        encoded = [encode_positions(bank.to_unit(points[i : i + 1], torch.tensor([i]))[0], directions, 1.0)
                   for i in range(n)]
    modules = [VMapMLP(width) for _ in range(n)]
    optimisers = [torch.optim.AdamW(m.parameters(), lr=1e-3, weight_decay=0.013) for m in modules]

    def module_loop_step() -> None:
        for i, (module, optimiser) in enumerate(zip(modules, optimisers)):
            optimiser.zero_grad(set_to_none=True)
            occupancy, colour = module(*encoded[i])
            ((occupancy - target_occ[i]).abs().mean() + (colour - target_rgb[i]).abs().mean()).backward()
            optimiser.step()

    t_loop = median_seconds(module_loop_step, max(5, repeats // 3))
    flops = 3 * mlp_flops_per_point(width) * n * p
    return {"instances": n, "points": p, "width": width, "batched_ms": t_batched * 1e3,
            "forward_ms": t_fwd * 1e3, "backward_ms": (t_fwd_bwd - t_fwd) * 1e3, "adam_ms": t_adam * 1e3,
            "batched_gflops": flops / t_batched / 1e9, "loop_modules_ms": t_loop * 1e3,
            "looped_forward_ms": t_looped_bank * 1e3, "speedup_vs_loop": t_loop / t_batched,
            "speedup_vs_looped_forward": t_looped_bank / t_batched}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--width", type=int, default=32)
    parser.add_argument("--keep-denormals", action="store_true", help="do not flush denormal floats to zero")
    parser.add_argument("--json", default=None, help="also write the figures to this JSON file")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    ftz = False if args.keep_denormals else torch.set_flush_denormal(True)
    torch.manual_seed(0)

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"torch {torch.__version__}, {torch.get_num_threads()} threads, flush denormals {ftz}, "
          f"load {os.getloadavg()[0]:.2f}")
    mm = matmul_gflops(max(5, args.repeats // 3))
    print(f"(a) 2048x2048 float32 matmul: {mm:.1f} GFLOP/s")
    rows = []
    print(f"(b, c) one training step, width {args.width}, MLP FLOPs x3 = {3 * mlp_flops_per_point(args.width)} per point")
    print(f"{'N x P':>10} {'batched':>8} {'fwd':>6} {'bwd':>6} {'adam':>6} {'GFLOP/s':>8} {'of mm':>6} "
          f"{'loop':>8} {'x':>5} {'looped_fwd':>10} {'x':>5}")
    for n, p in SETTINGS:
        r = bench_setting(n, p, args.width, args.repeats)
        r["of_matmul"] = r["batched_gflops"] / mm
        rows.append(r)
        print(f"{n:>4} x {p:<4} {r['batched_ms']:>6.1f}ms {r['forward_ms']:>6.1f} {r['backward_ms']:>6.1f} "
              f"{r['adam_ms']:>6.2f} {r['batched_gflops']:>8.1f} {100 * r['of_matmul']:>5.0f}% "
              f"{r['loop_modules_ms']:>6.1f}ms {r['speedup_vs_loop']:>5.2f} {r['looped_forward_ms']:>8.1f}ms "
              f"{r['speedup_vs_looped_forward']:>5.2f}")
    print("targets: batched >= 40% of matmul; >= 2x the loop at 100 x 120; not slower than the loop at 20 x 1200")
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"matmul_gflops": mm, "threads": args.threads, "rows": rows}, indent=2))
        os.replace(tmp, path)


if __name__ == "__main__":
    main()
