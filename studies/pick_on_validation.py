"""Pick the policy to ship on validation worlds: the training reward's return, on worlds no run trained on and
no test cell uses.

A run's ``best.json`` is picked by the rolling training return, whose noise is as large as the differences between
checkpoints (docs/learning.md); the unseen test cells (``studies.learned_vs_fixed``) must not choose either. So each
candidate plays each validation world with the
reward it was trained for (``--reward-baseline never_always`` with ``comm_cost_of_always``, or ``front``; the
baseline episodes are played once per world and cached), and the highest mean return is the choice. Rows go to ``--out/rows.jsonl``
as each episode ends (a rerun skips them); the table and the choice to ``--out/validation.md`` and
``--out/choice.json``.

Run: `.venv/bin/python -m studies.pick_on_validation --setting "rl_lite,link_range_m=2.5" --candidates
runs/learn/gate_range_s0/best.json runs/learn/gate_range_s0/latest.json ... --out docs/schedules/validation_range`
(about 12 s an episode here, plus the baseline episodes per world the first time). On a Ray cluster every
(world, candidate) is an independent task.

A world is ``random:SEED`` (a room like the training ones, played at ``--episode-seed``) or ``SCENE:SEED`` (a
furnished preset scene built and played at that seed, as ``studies.learned_vs_fixed``'s cells are): ``--worlds
furnished`` is room0 and office0 at seeds 6-8, scenes and seeds no test cell uses.

Figures: docs/learning.md#links-within-25-m-a-learned-gate-over-instance_novelty---payload-instance_novelty
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from openmulti_env.environment.config import env_config
from policies import make_policy
from studies.cells import FURNISHED_WORLDS, VALIDATION_WORLDS, split_world
from studies.episodes import env_for
from studies.rows import append_row, read_rows
from studies.settings import parse_setting


def validation_episode(env, policy, seed: int) -> dict:
    """One episode: the team's return (the training reward), final completion (percent) and MB sent."""
    observations, infos = env.reset(seed=seed)
    total, step = 0.0, 0
    while env.agents:
        actions = policy(observations if getattr(policy, "reads_observations", False) else None, infos, step)
        observations, rewards, _, _, infos = env.step(actions)
        total += float(np.mean(list(rewards.values())))
        step += 1
    if not np.isfinite(total):
        raise RuntimeError(f"the return of {policy!r} is not finite ({total}): the reward is broken, not the policy")
    return {"return": total, "completion": float(np.mean([i["completion_ratio"] for i in infos.values()])),
            "mb": float(sum(i["bytes_sent_total"] for i in infos.values()) / 1e6)}


def table(rows: list[dict], candidates: list[str]) -> tuple[str, str]:
    """The Markdown table (mean return ± standard error, completion, MB per candidate) and the chosen candidate."""
    lines = ["| candidate | worlds | return (mean ± SE) | completion % | MB |", "|---|---|---|---|---|"]
    means = {}
    for name in candidates:
        mine = [r for r in rows if r["policy"] == name]
        if not mine:
            continue
        returns = np.array([r["return"] for r in mine])
        se = returns.std(ddof=1) / np.sqrt(len(returns)) if len(returns) > 1 else float("nan")
        means[name] = float(returns.mean())
        lines.append(f"| `{name}` | {len(mine)} | {returns.mean():.3f} ± {se:.3f} | "
                     f"{np.mean([r['completion'] for r in mine]):.2f} | {np.mean([r['mb'] for r in mine]):.1f} |")
    if not means:
        raise RuntimeError("no candidate has a validation row")
    return "\n".join(lines) + "\n", max(means, key=means.get)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--setting", default="rl_lite", help="preset[,field=value...] as in training")
    parser.add_argument("--worlds", nargs="+", default=list(VALIDATION_WORLDS),
                        help="random:SEED or SCENE:SEED worlds, or `furnished` (" + " ".join(FURNISHED_WORLDS) + ")")
    parser.add_argument("--episode-seed", type=int, default=0)
    parser.add_argument("--comm-cost-of-always", type=float, default=0.3)
    parser.add_argument("--reward-baseline", choices=("never_always", "front"), default="never_always",
                        help="the training reward the candidates are compared under")
    parser.add_argument("--candidates", nargs="+", required=True, help="policy files (NAME:mode for a file's mode)")
    parser.add_argument("--out", default="runs/validation")
    args = parser.parse_args()
    worlds = [w for world in args.worlds for w in (FURNISHED_WORLDS if world == "furnished" else (world,))]
    preset, overrides = parse_setting(args.setting)
    overrides.update(reward_baseline=args.reward_baseline, comm_cost_of_always=args.comm_cost_of_always)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows_path = out / "rows.jsonl"
    rows = read_rows(rows_path)
    def key(row: dict) -> tuple:  # a row counts for this call only under the same reward and episode
        return (row["setting"], row.get("reward_baseline", "never_always"), row["comm_cost_of_always"],
                row["world"], row["episode_seed"], row["policy"])

    here = (args.setting, args.reward_baseline, args.comm_cost_of_always)
    done = {key(r) for r in rows}
    n = env_config(preset, **overrides).num_agents
    for world in worlds:
        scene, world_seed, episode_seed = split_world(world, args.episode_seed)
        envs: dict[str, object] = {}
        for name in args.candidates:
            if here + (world, episode_seed, name) in done:
                continue
            policy = make_policy(name, n, episode_seed)
            env = env_for(envs, policy, preset, scene=scene, seed=world_seed, **overrides)
            row = {"setting": args.setting, "episode_seed": episode_seed, "reward_baseline": args.reward_baseline,
                   "comm_cost_of_always": args.comm_cost_of_always, "world": world, "policy": name,
                   **validation_episode(env, policy, episode_seed)}
            rows.append(row)
            append_row(rows_path, row)
            print(f"{world} {name}: return {row['return']:.3f}, {row['completion']:.2f} %, {row['mb']:.1f} MB", flush=True)
        for env in envs.values():
            env.close()
    played = {(world, split_world(world, args.episode_seed)[2]) for world in worlds}
    mine = [r for r in rows if key(r)[:3] == here and (r["world"], r["episode_seed"]) in played]
    text, chosen = table(mine, list(args.candidates))
    reward = ("the margin over the fixed-rate front" if args.reward_baseline == "front"
              else f"never/always baselines, {args.comm_cost_of_always} x always's bytes")
    header = (f"Setting `{args.setting}`, validation worlds {', '.join(worlds)} (`random:SEED` at episode seed "
              f"{args.episode_seed}, `SCENE:SEED` at its seed), "
              f"the training reward ({reward}); one episode per world and candidate.\n\n")
    (out / "validation.md").write_text(header + text + f"\nChosen: `{chosen}` (the highest mean return).\n")
    (out / "choice.json").write_text(json.dumps({"chosen": chosen, "setting": args.setting, "worlds": worlds}) + "\n")
    print(header + text + f"\nChosen: {chosen}")


if __name__ == "__main__":
    main()
