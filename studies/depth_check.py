"""The depth check on a run (issue target: the simulator's maps at most 8 % of valid pixels off by > 5 cm or
without surface; real sequences at most 10 % and a median error of at most 2 cm).

Runs `openmulti run` on a scene (or ``--data``) with every ``--holdout-every``-th frame kept out of the maps,
and prints per agent the depth check on the frames the map trained on and on the held-out ones, beside
the run's culled accuracy and completion ratio.

Run: `.venv/bin/python -m studies.depth_check [--scene room0] [--preset demo] [--agents 4]
[--holdout-every 10] [--data FOLDER] [--out runs/bench_depth_check]`.

Figures: docs/real_data.md#a-small-real-data-suite
"""

from __future__ import annotations

import argparse
import os
import shutil
from pathlib import Path

from mapping.pipeline.records import write_json_atomic
from openmulti_env.runs.run import run, run_data


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="room0")
    parser.add_argument("--data", help="a data set folder instead of --scene (as openmulti run --data)")
    parser.add_argument("--preset", default="demo")
    parser.add_argument("--agents", type=int, default=4)
    parser.add_argument("--policy", default="always")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--holdout-every", type=int, default=10)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", default="runs/bench_depth_check")
    args = parser.parse_args()
    name = Path(args.data).name if args.data else args.scene
    out = Path(args.out) / f"{name}_{args.preset}_a{args.agents}_h{args.holdout_every}"
    shutil.rmtree(out, ignore_errors=True)  # a study measures a fresh run
    options = dict(device="cpu", threads=args.threads, holdout_every=args.holdout_every)
    if args.data:
        metrics = run_data(args.data, args.agents, args.policy, args.preset, args.seed, out, **options)
    else:
        metrics = run(args.scene, args.agents, args.policy, args.preset, args.seed, out, **options)
    print(f"\n{name}, preset {args.preset}, {args.agents} agents, policy {args.policy}, every {args.holdout_every}th "
          f"frame held out (load average {os.getloadavg()[0]:.2f})")
    print(f"{'agent':<8} {'acc [cm]':>9} {'CR [%]':>7} {'seen: err [cm]':>15} {'off [%]':>8} {'no surf [%]':>11} "
          f"{'held out: err [cm]':>19} {'off [%]':>8}")
    for agent, m in list(metrics["agents"].items()) + [("mean", metrics["mean"])]:
        print(f"{agent:<8} {_fmt(m.get('acc_cm')):>9} {_fmt(m.get('comp_ratio')):>7} "
              f"{_fmt(m.get('depth_median_cm')):>15} {_fmt(m.get('depth_off_pct')):>8} "
              f"{_fmt(m.get('depth_no_surface_pct')):>11} {_fmt(m.get('depth_heldout_median_cm')):>19} "
              f"{_fmt(m.get('depth_heldout_off_pct')):>8}")
    write_json_atomic(out / "bench.json", {"agents": metrics["agents"], "mean": metrics["mean"],
                                            "holdout_every": args.holdout_every, "preset": args.preset})


if __name__ == "__main__":
    main()
