"""The held-out comparison of communication policies from ``studies.schedules``' rows: completion against
bytes, each policy against `always` on the same episodes, and the fixed-rate baseline at equal bytes.

The issue's targets, read from the rows (every (setting, seed) episode that every listed policy has):
- within 2 points of `always`'s completion at <= 40 % of its bytes (goal 25 %);
- a policy beats the best fixed-rate schedule that spends the same bytes: for each episode, the fixed-rate
  front (`never`, `every:K`, `rate:Q`, `always`: the upper envelope of their (MB, completion) points,
  linear between them) read at the policy's MB.

Run: `.venv/bin/python -m studies.schedules_tradeoff docs/schedules/heldout/rows.jsonl --png docs/schedules/heldout.png`
(prints Markdown; the PNG has one panel per setting).

Figures: docs/schedules.md#held-out-episodes-at-rl_small-studiesschedulespy-studiesschedules_tradeoffpy
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import numpy as np

from studies.fronts import concave_front_at, is_fixed_rate
from studies.rows import read_rows


def load_rows(path: Path) -> dict[tuple[str, int], dict[str, dict]]:
    """{(setting, seed): {policy: row}}."""
    episodes: dict[tuple[str, int], dict[str, dict]] = defaultdict(dict)
    for row in read_rows(path):
        episodes[(row["setting"], row["seed"])][row["policy"]] = row
    return episodes


def policy_names(episodes: dict[tuple[str, int], dict[str, dict]]) -> list[str]:
    """Every policy in the rows, fixed-rate ones first."""
    return sorted({p for rows in episodes.values() for p in rows}, key=lambda p: (not is_fixed_rate(p), p))


def short(policy: str) -> str:
    """A policy file by its run folder and stem (``runs/x/best.json:mode`` -> ``x/best:mode``), so that two
    runs' ``best`` stay apart."""
    base, mode = (policy[:-len(":mode")], ":mode") if policy.endswith(":mode") else (policy, "")
    if not base.endswith(".json"):
        return policy
    folder = Path(base).parent.name
    return f"{folder}/{Path(base).stem}{mode}" if folder else f"{Path(base).stem}{mode}"


def summary(episodes: dict[tuple[str, int], dict[str, dict]]) -> str:
    """Markdown: per policy, over the episodes every policy has, means and paired differences."""
    policies = policy_names(episodes)
    complete = {k: v for k, v in episodes.items() if set(v) == set(policies) and "always" in v}
    lines = [f"{len(complete)} episodes ({', '.join(sorted({s for s, _ in complete}))}; seeds "
             f"{sorted({seed for _, seed in complete})}) where every policy ran.", "",
             "| policy | completion % | MB (team) | of always's bytes | vs always [points] | vs fixed rate at equal MB [points] |",
             "|---|---|---|---|---|---|"]
    for p in policies:
        comp = np.array([rows[p]["completion"] for rows in complete.values()])
        mb = np.array([rows[p]["mb"] for rows in complete.values()])
        share = np.array([rows[p]["mb"] / rows["always"]["mb"] for rows in complete.values()])
        gain = comp - np.array([rows["always"]["completion"] for rows in complete.values()])
        vs_front = np.array([rows[p]["completion"] - concave_front_at(
            [(r["mb"], r["completion"]) for q, r in rows.items() if is_fixed_rate(q)], rows[p]["mb"])
            for rows in complete.values()])
        lines.append(f"| {short(p)} | {comp.mean():.1f} ± {comp.std(ddof=1) if len(comp) > 1 else 0:.1f} | "
                     f"{mb.mean():.1f} | {100 * share.mean():.0f} % | {gain.mean():+.1f} "
                     f"(min {gain.min():+.1f}) | {vs_front.mean():+.1f} (min {vs_front.min():+.1f}, max "
                     f"{vs_front.max():+.1f}) |")
    return "\n".join(lines)


def plot(episodes: dict[tuple[str, int], dict[str, dict]], out: Path) -> None:
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    settings = sorted({s for s, _ in episodes})
    policies = policy_names(episodes)
    fig, axes = plt.subplots(1, len(settings), figsize=(5 * len(settings), 4.2), squeeze=False)
    colours = {p: plt.cm.tab20(i % 20) for i, p in enumerate(policies)}
    for ax, setting in zip(axes[0], settings):
        for p in policies:
            pts = [(rows[p]["mb"], rows[p]["completion"]) for (s, _), rows in episodes.items() if s == setting and p in rows]
            if pts:
                x, y = zip(*pts)
                ax.scatter(x, y, color=colours[p], marker="o" if is_fixed_rate(p) else "*",
                           s=30 if is_fixed_rate(p) else 120, label=short(p), edgecolors="k", linewidths=0.3)
        ax.set_title(setting.replace("rl_small,scene=", "rl_small, "))
        ax.set_xlabel("MB sent by the team per episode")
        ax.set_ylabel("final completion % (env estimate)")
        ax.grid(alpha=0.3)
    axes[0][-1].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("rows", type=Path)
    parser.add_argument("--png", type=Path)
    args = parser.parse_args()
    if not args.rows.is_file():
        raise SystemExit(f"no rows file at {args.rows}: run python -m studies.schedules --out first")
    episodes = load_rows(args.rows)
    print(summary(episodes))
    if args.png:
        plot(episodes, args.png)
        print(f"\nwrote {args.png}")


if __name__ == "__main__":
    main()
