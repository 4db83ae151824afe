"""How much of a return is the world and how much the schedule: the raw reward against the normalised one.

For each training world (``random:SEED`` rooms, never a reported scene) and one episode seed, fixed schedules
play the same episode on the env with ``reward_baseline="never_always"``; each row keeps both returns: the raw
one (final team completion minus ``comm_cost_per_mb`` x MB / N, what the env pays with ``reward_baseline="none"``)
and the normalised one (the sum of the rewards paid). The table gives, per schedule, the mean and the spread
(standard deviation) across worlds of each return, and the ratio that decides whether a policy gradient can
tell schedules apart from a handful of episodes: the spread of one schedule's return across worlds over the
mean gap between two schedules (lower is better).

Run: `.venv/bin/python -m studies.reward_spread --setting rl_lite --worlds 100 101 102 103 104 105
--policies always never every:2 every:3 every:4 rate:0.5 --out docs/schedules/reward_spread` (about 25 s an
episode here; the never/always baselines are the env's own, cached). Rows go to ``--out/rows.jsonl`` as each
episode ends (a rerun skips them); ``--out/reward_spread.md`` holds the table.

Figures: docs/learning.md#the-reward-one-scale-in-every-world---reward-baseline-never_always
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import numpy as np

from openmulti_env import parallel_env
from policies import make_policy
from studies.rows import append_row, read_rows
from studies.settings import parse_setting


def play(env, policy, seed: int) -> dict:
    """One episode: the normalised return (the env's rewards), the final team completion (%) and team MB."""
    observations, infos = env.reset(seed=seed)
    total, step, start = 0.0, 0, time.perf_counter()
    while env.agents:
        actions = policy(observations, infos, step)
        observations, rewards, _, _, infos = env.step(actions)
        total += rewards["agent_0"]
        step += 1
    completion = float(np.mean([i["completion_ratio"] for i in infos.values()]))
    mb = float(sum(i["bytes_sent_total"] for i in infos.values()) / 1e6)
    return {"normalised": total, "completion": completion, "mb": mb, "steps": step,
            "wall_s": time.perf_counter() - start}


def table(rows: list[dict], cost_per_mb: float) -> str:
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    worlds = sorted({r["world"] for r in rows})
    n = rows[0]["num_agents"]
    value = {(r["world"], r["policy"]): r for r in rows}
    raw = {k: r["completion"] / 100 - cost_per_mb * r["mb"] / n for k, r in value.items()}
    norm = {k: r["normalised"] for k, r in value.items()}
    lines = [f"{len(worlds)} worlds ({', '.join(worlds)}), one episode each; raw: final team completion - "
             f"{cost_per_mb}/MB x MB / {n}; normalised: the env's `never_always` return.", "",
             "| schedule | raw mean | raw spread | normalised mean | normalised spread |", "|---|---|---|---|---|"]
    for p in policies:
        a = [raw[w, p] for w in worlds if (w, p) in raw]
        b = [norm[w, p] for w in worlds if (w, p) in norm]
        lines.append(f"| `{p}` | {np.mean(a):.4f} | {np.std(a, ddof=1) if len(a) > 1 else float('nan'):.4f} | "
                     f"{np.mean(b):.4f} | {np.std(b, ddof=1) if len(b) > 1 else float('nan'):.4f} |")
    sending = [p for p in policies if p not in ("never", "always")]
    lines += ["", "Spread of a schedule across worlds over the mean gap between two schedules (the same worlds), "
              "for each pair of the sending schedules:", "",
              "| pair | raw gap | raw spread / gap | normalised gap | normalised spread / gap |", "|---|---|---|---|---|"]
    ratios = {"raw": [], "normalised": []}
    for p, q in itertools.combinations(sending, 2):
        common = [w for w in worlds if (w, p) in raw and (w, q) in raw]
        if len(common) < 2:
            continue
        cells = []
        for name, src in (("raw", raw), ("normalised", norm)):
            gap = abs(np.mean([src[w, p] - src[w, q] for w in common]))
            spread = np.mean([np.std([src[w, s] for w in common], ddof=1) for s in (p, q)])
            ratios[name].append(spread / max(gap, 1e-9))
            cells += [f"{gap:.4f}", f"{spread / max(gap, 1e-9):.1f}"]
        lines.append(f"| `{p}` vs `{q}` | " + " | ".join(cells) + " |")
    if ratios["raw"]:
        lines += ["", f"Median spread / gap: raw {np.median(ratios['raw']):.1f}, normalised "
                      f"{np.median(ratios['normalised']):.1f}."]
    # the completion part alone (the costs are the same in every world): points against the share of always's gain
    if all((w, p) in value for w in worlds for p in ("never", "always")):
        points = {k: r["completion"] for k, r in value.items()}
        share = {(w, p): (points[w, p] - points[w, "never"]) / max(points[w, "always"] - points[w, "never"], 2.0)
                 for (w, p) in points}  # floored at 2 points, as the env's reward (GAIN_FLOOR)
        lines += ["", "The completion part alone (costs do not vary between worlds): final completion in points "
                  "against the share of `always`'s gain over `never` that the schedule reached; paired sd is the "
                  "standard deviation over worlds of the difference between the two schedules.", "",
                  "| pair | points: gap | spread / gap | paired sd | share: gap | spread / gap | paired sd |",
                  "|---|---|---|---|---|---|---|"]
        parts = {"points": [], "share": []}
        for p, q in itertools.combinations(sending, 2):
            common = [w for w in worlds if (w, p) in points and (w, q) in points]
            if len(common) < 2:
                continue
            cells = []
            for name, src in (("points", points), ("share", share)):
                diff = [src[w, p] - src[w, q] for w in common]
                spread = np.mean([np.std([src[w, s] for w in common], ddof=1) for s in (p, q)])
                parts[name].append(spread / max(abs(np.mean(diff)), 1e-9))
                cells += [f"{np.mean(diff):+.3f}", f"{parts[name][-1]:.1f}", f"{np.std(diff, ddof=1):.3f}"]
            lines.append(f"| `{p}` vs `{q}` | " + " | ".join(cells) + " |")
        if parts["points"]:
            lines += ["", f"Median spread / gap of the completion part: points {np.median(parts['points']):.2f}, "
                          f"share {np.median(parts['share']):.2f}."]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--setting", default="rl_lite")
    parser.add_argument("--worlds", type=int, nargs="+", default=[100, 101, 102, 103, 104, 105])
    parser.add_argument("--policies", nargs="+", default=["always", "never", "every:2", "every:3", "every:4", "rate:0.5"])
    parser.add_argument("--episode-seed", type=int, default=0)
    parser.add_argument("--out", default="runs/reward_spread")
    args = parser.parse_args()
    preset, overrides = parse_setting(args.setting)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows_path = out / "rows.jsonl"
    rows = read_rows(rows_path)
    done = {(r["setting"], r["world"], r["policy"], r["episode_seed"]) for r in rows}
    cost = None
    for world in args.worlds:
        env = parallel_env(preset=preset, scene=f"random:{world}", reward_baseline="never_always", **overrides)
        cost = env.config.env.comm_cost_per_mb
        n = env.config.num_agents
        for name in args.policies:
            key = (args.setting, f"random:{world}", name, args.episode_seed)
            if key in done:
                continue
            result = play(env, make_policy(name, n, seed=args.episode_seed), args.episode_seed)
            row = {"setting": args.setting, "world": f"random:{world}", "policy": name,
                   "episode_seed": args.episode_seed, "num_agents": n, **result}
            rows.append(row)
            append_row(rows_path, row)
            print(f"{row['world']} {name}: completion {row['completion']:.2f} % MB {row['mb']:.1f} normalised "
                  f"{row['normalised']:.3f} ({row['wall_s']:.0f} s)", flush=True)
        env.close()
    if cost is None:
        from openmulti_env.environment.config import env_config  # noqa: PLC0415

        cost = env_config(preset, **overrides).env.comm_cost_per_mb
    mine = [r for r in rows if r["setting"] == args.setting and r["episode_seed"] == args.episode_seed]
    text = table(mine, cost)
    (out / "reward_spread.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
