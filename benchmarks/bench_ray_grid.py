"""The reproduction grid on Ray against the sequential runner, side by side in one process.

The same grid (by default Table V's four `openmulti` runs on the `tiny` scene at preset `tiny`), first one run
at a time, then as Ray tasks on a local Ray with ``--workers`` CPUs (one per run), each into a fresh
folder. Prints wall times, the ratio, and whether both made the same rows: every metric but the
times alike, and how many bytes apart (processes differ at float level here, which can change the
length of a number in a message header by a few bytes: the README's limits).

Run: `.venv/bin/python benchmarks/bench_ray_grid.py [--workers 2] [--out runs/bench_ray_grid]`.
Writes `OUT/bench_ray_grid.json`.

Figures: docs/ray.md#measured-here, docs/benchmarks.md#the-grid-on-ray
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import time
from pathlib import Path

from mapping.pipeline.records import write_json_atomic
from openmulti_env.runs.reproduce.runner import run_table
from openmulti_env.runs.reproduce.tables import RunSpec, table_runs


def timed_grid(specs: list[RunSpec], preset: str, out: Path, ray_address: str | None) -> tuple[float, list[dict]]:
    shutil.rmtree(out, ignore_errors=True)
    start = time.perf_counter()
    rows = run_table(specs, preset, out, threads=1, three_cullings=False, progress=True, ray_address=ray_address)
    return time.perf_counter() - start, rows


TIMES = ("run_s", "wall_s", "fleet_s", "compute_s_max", "time_per_round_s")
BYTES = ("mb_total", "bytes_per_round", "bytes_per_round_series")


def compare_rows(a: list[dict], b: list[dict]) -> tuple[list[bool], float]:
    """Per row pair: the metrics but times and bytes equal; and the largest difference in bytes sent."""
    keep = lambda row: {k: v for k, v in row.items() if k not in TIMES + BYTES}  # noqa: E731
    same = [keep(x) == keep(y) for x, y in zip(a, b)]
    return same, max(abs(x["mb_total"] - y["mb_total"]) * 1e6 for x, y in zip(a, b))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2, help="CPUs of the local Ray (one run each)")
    parser.add_argument("--preset", default="tiny")
    parser.add_argument("--scene", default="tiny")
    parser.add_argument("--out", default="runs/bench_ray_grid")
    args = parser.parse_args()
    import ray  # noqa: PLC0415

    out = Path(args.out)
    specs = [s for s in table_runs("comm-failure", [args.scene], [0]) if s.method == "openmulti"]
    sequential_s, sequential = timed_grid(specs, args.preset, out / "sequential", None)
    ray.init(num_cpus=args.workers, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        ray_s, on_ray = timed_grid(specs, args.preset, out / "ray", "local")
    finally:
        ray.shutdown()
    same, bytes_apart = compare_rows(sequential, on_ray)
    result = {"runs": len(specs), "preset": args.preset, "scene": args.scene, "workers": args.workers,
              "sequential_s": sequential_s, "ray_s": ray_s, "speedup": sequential_s / ray_s,
              "same_metrics": same, "bytes_apart_max": bytes_apart,
              "machine": f"{platform.machine()} ({os.cpu_count()} cores)"}
    write_json_atomic(out / "bench_ray_grid.json", result)
    print(f"| runs | sequential [s] | Ray, {args.workers} workers [s] | speed-up | same metrics | bytes apart (max) |")
    print("|---|---|---|---|---|---|")
    print(f"| {len(specs)} | {sequential_s:.1f} | {ray_s:.1f} | {sequential_s / ray_s:.2f}x | {sum(same)}/{len(same)} "
          f"| {bytes_apart:.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
