"""Where schedules matter: final completion and megabytes of communication policies on env episodes.

For each env setting (a preset with optional overrides) and each policy, whole episodes on the env (the
env's own completion estimate, the reward's view) with the same world and episode seeds, side by side:
final completion ratio (team mean, percent), MB sent by the team, seconds per step. Also what each half
of the action is worth: ``params_only`` (parameters, no rays) and ``rays_only``.

Run: `.venv/bin/python benchmarks/bench_schedules.py --setting rl --setting "rl,frames_per_agent=60" \
--policies always never every:3 rate:0.3 novelty params_only rays_only --seeds 0 1 --out runs/bench_schedules`.
Each finished row is appended to `--out/rows.jsonl` at once (a rerun skips the rows it has); prints a
Markdown table per setting and writes `--out/schedules.json`.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from mapping.pipeline.records import write_json_atomic
from openmulti_env import parallel_env
from openmulti_env.environment.config import env_config
from policies import make_policy


class HalfPolicy:
    """``always`` on one half of the action: parameters without rays, or rays without parameters."""

    reads_observations = False

    def __init__(self, half: str, num_agents: int):
        self.half, self.n = half, num_agents

    def __call__(self, observations, infos, step):
        ones, zeros = np.ones(self.n - 1, np.int8), np.zeros(self.n - 1, np.int8)
        first, second = (ones, zeros) if self.half == "params_only" else (zeros, ones)
        return {f"agent_{i}": np.concatenate([first, second]) for i in range(self.n)}


def parse_setting(text: str) -> tuple[str, dict]:
    """``"rl,frames_per_agent=60,scene=office0"`` -> (preset, overrides)."""
    preset, *items = text.split(",")
    overrides = {}
    for item in items:
        key, _, value = item.partition("=")
        for kind in (int, float):
            try:
                overrides[key] = kind(value)
                break
            except ValueError:
                continue
        else:
            overrides[key] = value
    return preset, overrides


def env_for(envs: dict, policy, preset: str, **env_kwargs):
    """The env in ``policy``'s action form (``instance_novelty`` and gates over it act in ``instances``), made once
    per form and kept in ``envs``."""
    form = getattr(policy, "action_form", "entries")
    if form not in envs:
        envs[form] = parallel_env(preset=preset, **{**env_kwargs, "action_form": form})
    return envs[form]


def append_row(path: Path, row: dict) -> None:
    """One finished episode's row, appended at once (a rerun skips the rows already there)."""
    with path.open("a") as f:
        f.write(json.dumps(row) + "\n")


def episode(env, policy, seed: int) -> dict:
    """One episode: final completion (team mean, percent), MB sent, steps, seconds per step."""
    obs, infos = env.reset(seed=seed)
    start, steps = time.perf_counter(), 0
    while env.agents:
        actions = policy(obs if getattr(policy, "reads_observations", False) else None, infos, steps)
        obs, _, _, _, infos = env.step(actions)
        steps += 1
    wall = time.perf_counter() - start
    return {"completion": float(np.mean([i["completion_ratio"] for i in infos.values()])),
            "mb": float(sum(i["bytes_sent_total"] for i in infos.values()) / 1e6), "steps": steps,
            "s_per_step": wall / max(steps, 1)}


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
    rows = [json.loads(line) for line in rows_file.read_text().splitlines()] if rows_file.exists() else []
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
