"""Single-agent mapping study (issue targets: room0, preset fast, all frames: completion ratio >= 85%,
accuracy <= 2.5 cm, <= 5 minutes on a 2-core CPU; preset full reports its own figures).

Run: `.venv/bin/python -m studies.single_agent [--scene room0] [--preset fast] [--out runs/bench_mapping]`.
Prints the metrics, the wall time and the peak memory (max RSS) of the run.

Figures: docs/benchmarks.md#one-agent-room0-fast-across-the-history-studiessingle_agentpy
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import shutil
import time
from pathlib import Path

import torch

from mapping.pipeline.records import write_json_atomic
from openmulti_env.runs.run import run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--scene", default="room0")
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/bench_mapping")
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1,
                        help="torch threads (use 1 when another process shares the cores)")
    args = parser.parse_args()
    out = Path(args.out) / f"{args.scene}_{args.preset}"
    shutil.rmtree(out, ignore_errors=True)  # a study measures a fresh run, never a resumed one
    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    result = run(args.scene, 1, "never", args.preset, args.seed, out, device="cpu")
    wall = time.perf_counter() - start
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    m = result["agents"]["agent_0"]
    print(f"\nmachine: {platform.machine()}, {os.cpu_count()} cores, {args.threads} torch threads, "
          f"torch {torch.__version__}, CPU, load average {os.getloadavg()[0]:.2f}")
    print(f"{args.scene} preset {args.preset}, 1 agent, all frames: acc {m['acc_cm']:.2f} cm, comp {m['comp_cm']:.2f} cm, "
          f"comp ratio {m['comp_ratio']:.1f} %, {m['instances']} instances "
          f"(acc of the unculled reconstruction {m['acc_cm_unculled']:.2f} cm)")
    print(f"wall {wall:.0f} s (incl. world build and meshing), peak memory {peak_gb:.2f} GB")
    write_json_atomic(out / "bench.json", {"metrics": m, "wall_s": wall, "peak_rss_gb": peak_gb,
                                            "cores": os.cpu_count(),
                                            "threads": args.threads, "load_average": os.getloadavg()[0]})


if __name__ == "__main__":
    main()
