"""Memory per env when one process steps several worlds (``openmulti train --worlds-per-worker K``).

For each K, a fresh process builds the training vector env as ``openmulti train`` does (``WorkerEnvs`` over
the default training worlds, ``policies.sb3_vec.sb3_vec_env_from_factory`` with one worker), steps every
world through ``--episodes`` whole episodes with random actions, and reports its peak RSS (``VmHWM``) and its
RSS at the end. Per env is peak / K: what K worlds in one process cost each, against K worker processes of
one world each (K x the K=1 row).

    .venv/bin/python benchmarks/bench_vector_memory.py --preset rl_small --worlds 1 2 4

Figures: docs/profile.md#the-training-episode-rl_small-where-a-step-goes-and-memory-per-env-issue-47-2026-12-06
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def status_mb(key: str) -> float:
    """A ``/proc/self/status`` size (``VmRSS``, ``VmHWM``) in MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024.0
    raise KeyError(key)


def one(preset: str, worlds: int, episodes: int, steps_per_episode: int) -> dict:
    """K worlds in this process: the vector env, ``episodes`` episodes of random actions, its memory."""
    from openmulti_env.runs.train import DEFAULT_TRAIN_SCENES, WorkerEnvs
    from policies.sb3_vec import sb3_vec_env_from_factory

    start = time.perf_counter()
    factory = WorkerEnvs(DEFAULT_TRAIN_SCENES, worlds, 2, {"preset": preset})
    vec, num_agents = sb3_vec_env_from_factory(factory, workers=1, seed=0, worlds_per_worker=worlds)
    rng = np.random.default_rng(0)
    vec.reset()
    steps = 0
    for _ in range(episodes * steps_per_episode):
        actions = rng.integers(0, 2, size=(vec.num_envs, *vec.action_space.shape)).astype(np.int8)
        vec.step(actions)
        steps += 1
    vec.close()
    return {"preset": preset, "worlds": worlds, "agents": num_agents, "vector_steps": steps,
            "env_steps": steps * worlds, "wall_s": time.perf_counter() - start,
            "peak_rss_mb": status_mb("VmHWM"), "end_rss_mb": status_mb("VmRSS")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="rl_small")
    parser.add_argument("--worlds", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--episodes", type=int, default=1)
    parser.add_argument("--steps-per-episode", type=int, default=12, help="the preset's episode length")
    parser.add_argument("--one", type=int, help=argparse.SUPPRESS)  # the child process's K
    parser.add_argument("--out", help="also write the rows to this JSON")
    args = parser.parse_args()
    if min(args.worlds) < 1 or (args.one is not None and args.one < 1):
        parser.error("--worlds must be at least 1")
    if args.one is not None:
        print(json.dumps(one(args.preset, args.one, args.episodes, args.steps_per_episode)))
        return
    rows = []
    for k in args.worlds:
        done = subprocess.run([sys.executable, __file__, "--one", str(k), "--preset", args.preset, "--episodes",
                               str(args.episodes), "--steps-per-episode", str(args.steps_per_episode)],
                              cwd=ROOT, capture_output=True, text=True, check=True)
        row = json.loads(done.stdout.strip().splitlines()[-1])
        rows.append(row)
        print(f"{row['preset']}: {k} world(s) in one process: peak RSS {row['peak_rss_mb']:.0f} MB = "
              f"{row['peak_rss_mb'] / k:.0f} MB per env (end {row['end_rss_mb']:.0f} MB); {row['env_steps']} env "
              f"steps in {row['wall_s']:.0f} s", flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
