"""Profiles behind docs/profile.md: where an env step's time goes, and where a finished run's evaluation goes.

Run:
  `.venv/bin/python benchmarks/profile_costs.py env --preset rl_tiny --episodes 3`
      env steps with random actions after one warm-up episode, one torch thread and one agent worker
      thread (so cProfile, which sees one thread, sees every call).
  `.venv/bin/python benchmarks/profile_costs.py evaluation --out runs/demo [run options]`
      `openmulti run` again in a directory that holds a finished run's checkpoint: the run resumes after
      its last round, so only the evaluation (meshing, culling, scoring, pictures) is profiled. The run
      options must be the ones the checkpoint was made with (default: `make demo`'s).

Prints the top functions by cumulative time and writes the raw profile to `--stats` (read it with
`python -m pstats`).

Figures: docs/profile.md
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time
from pathlib import Path

import numpy as np


def profile_env(preset: str, episodes: int, cache_dir: str | None) -> cProfile.Profile:
    from openmulti_env import parallel_env  # noqa: PLC0415

    env = parallel_env(preset=preset, cache_dir=cache_dir, threads=1, workers=1)
    rng = np.random.default_rng(0)

    def actions() -> dict:
        return {a: rng.integers(0, 2, env.action_space(a).shape).astype(np.int8) for a in env.agents}

    env.reset(seed=0)  # warm-up: renders the frames and loads the encoder
    while env.agents:
        env.step(actions())
    profiler, steps, start = cProfile.Profile(), 0, time.perf_counter()
    profiler.enable()
    for episode in range(1, episodes + 1):
        env.reset(seed=episode)
        while env.agents:
            env.step(actions())
            steps += 1
    profiler.disable()
    seconds = time.perf_counter() - start
    print(f"{preset}: {steps} steps in {seconds:.1f} s under the profiler ({steps / seconds:.2f} steps/s)")
    return profiler


def profile_evaluation(run_args: list[str]) -> cProfile.Profile:
    from openmulti_env.runs.cli import main  # noqa: PLC0415

    profiler, start = cProfile.Profile(), time.perf_counter()
    profiler.enable()
    main(["run", *run_args])
    profiler.disable()
    print(f"evaluation: {time.perf_counter() - start:.1f} s under the profiler")
    return profiler


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    env = sub.add_parser("env", help="env steps")
    env.add_argument("--preset", default="rl_tiny")
    env.add_argument("--episodes", type=int, default=3)
    env.add_argument("--cache-dir", default=None)
    ev = sub.add_parser("evaluation", help="a finished run's evaluation")
    ev.add_argument("--out", default="runs/demo")
    ev.add_argument("run_options", nargs=argparse.REMAINDER,
                    help="options of `openmulti run` (default: make demo's)")
    for p in (env, ev):
        p.add_argument("--top", type=int, default=40)
        p.add_argument("--stats", default=None, help="write the raw profile here")
    args = parser.parse_args()
    if args.what == "env":
        if args.episodes < 1:
            parser.error("--episodes must be at least 1")
        profiler = profile_env(args.preset, args.episodes, args.cache_dir)
    else:
        checkpoint = Path(args.out) / "checkpoints" / "team.pt"
        if not checkpoint.is_file():
            parser.error(f"{checkpoint} does not exist: run the mapping first (e.g. `make demo OUT={args.out}`), "
                         "then profile its evaluation")
        options = args.run_options or ["--scene", "room0", "--agents", "4", "--policy", "always",
                                       "--alignment", "paper", "--preset", "demo"]
        profiler = profile_evaluation([*options, "--out", args.out])
    if args.stats:
        profiler.dump_stats(args.stats)
    pstats.Stats(profiler).sort_stats("cumulative").print_stats(args.top)


if __name__ == "__main__":
    main()
