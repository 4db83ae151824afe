"""Where schedules matter: final completion and megabytes of communication policies on env episodes.

For each env setting (a preset with optional overrides) and each policy, whole episodes on the env (the
env's own completion estimate, the reward's view) with the same world and episode seeds, side by side:
final completion ratio (team mean, percent), MB sent by the team, seconds per step. Also what each half
of the action is worth: ``params_only`` (parameters, no rays) and ``rays_only``.

Run: `.venv/bin/python -m studies.schedules --setting rl --setting "rl,frames_per_agent=60" \
--policies always never every:3 rate:0.3 novelty params_only rays_only --seeds 0 1 --out runs/bench_schedules`.
Each finished row is appended to `--out/rows.jsonl` at once (a rerun skips the rows it has); prints a
Markdown table per setting and writes `--out/schedules.json`.

Figures: docs/schedules.md#where-schedules-matter-studiesschedulespy
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mapping.pipeline.records import write_json_atomic
from openmulti_env.environment.config import env_config
from policies import make_policy
from studies.episodes import env_for, episode
from studies.rows import append_row, read_rows
from studies.settings import parse_setting


class HalfPolicy:
    """``always`` on one half of the action: parameters without rays, or rays without parameters."""

    reads_observations = False

    def __init__(self, half: str, num_agents: int) -> None:
        self.half, self.n = half, num_agents

    def __call__(self, observations, infos, step: int) -> dict[str, np.ndarray]:
        ones, zeros = np.ones(self.n - 1, np.int8), np.zeros(self.n - 1, np.int8)
        first, second = (ones, zeros) if self.half == "params_only" else (zeros, ones)
        return {f"agent_{i}": np.concatenate([first, second]) for i in range(self.n)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--setting", action="append", default=None, help="preset[,field=value...] (repeatable)")
    parser.add_argument("--policies", nargs="+", default=["always", "never", "every:3", "rate:0.3", "novelty",
                                                          "params_only", "rays_only"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--out", default="runs/bench_schedules")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows_file = out / "rows.jsonl"
    rows = read_rows(rows_file)
    done = {(r["setting"], r["policy"], r["seed"]) for r in rows}
    for setting in args.setting or ["rl"]:
        preset, overrides = parse_setting(setting)
        envs: dict[str, object] = {}  # one env per action form, made when a policy needs it
        n = env_config(preset, **overrides).num_agents
        for name in args.policies:
            for seed in args.seeds:
                if (setting, name, seed) in done:
                    continue
                policy = HalfPolicy(name, n) if name in ("params_only", "rays_only") else make_policy(name, n, seed)
                row = {"setting": setting, "policy": name, "seed": seed,
                       **episode(env_for(envs, policy, preset, **overrides), policy, seed)}
                rows.append(row)
                append_row(rows_file, row)
                print(f"{setting:40s} {name:14s} seed {seed}: {row['completion']:.1f} % {row['mb']:.1f} MB "
                      f"{row['s_per_step']:.2f} s/step", flush=True)
        for env in envs.values():
            env.close()
    write_json_atomic(out / "schedules.json", {"rows": rows})
    for setting in dict.fromkeys(r["setting"] for r in rows):
        print(f"\n### {setting}\n\n| policy | completion % | MB | s / step | episodes |\n|---|---|---|---|---|")
        for name in dict.fromkeys(r["policy"] for r in rows if r["setting"] == setting):
            mine = [r for r in rows if r["setting"] == setting and r["policy"] == name]
            print(f"| {name} | {np.mean([r['completion'] for r in mine]):.1f} | {np.mean([r['mb'] for r in mine]):.1f} "
                  f"| {np.mean([r['s_per_step'] for r in mine]):.2f} | {len(mine)} |")


if __name__ == "__main__":
    main()
