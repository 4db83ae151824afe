"""Learned schedules against the fixed-rate front and ``instance_novelty`` at equal bytes, on unseen cells.

Each cell is a scene and world seed no training run used (3 scenes x 3 seeds by default; training walks
``random:SEED`` rooms); every policy plays the cell's one episode (reset with the world seed) on the env
(the env's completion estimate, team mean, and the MB the team sent). Per cell, two fronts in (MB, completion):

- the fixed-rate front: ``never``, ``every:K``, ``rate:Q``, ``always``, their upper envelope, linear between points;
- the instance front: ``never``, ``instance_novelty`` at its settings (from each network once at its final state
  up to the default), ``always``, the same way.

A policy's margin over a front is its completion minus the front's at the policy's MB (paired: the same cell).
The table gives, per learned policy, the mean margin over the cells, its standard error, and whether it clears
two standard errors. Rows go to ``--out/rows.jsonl`` as each episode ends (a rerun skips them); the table to
``--out/learned_vs_fixed.md`` and a picture of the fronts to ``--out/fronts.png``.

Run: `.venv/bin/python -m studies.learned_vs_fixed --setting rl_lite --learned runs/learn/team_s0/best.json
--out docs/schedules/learned_unlimited` (about 12 s an episode here; 9 cells x 13 policies is about 25 minutes).
Link scenarios: `--setting "rl_lite,link_range_m=2.5"` or `"rl_lite,link_mb_per_round=0.25"`. On a Ray cluster
every (cell, policy) is an independent task (``studies.fast_runs.command`` shows the pattern).

Figures: docs/learning.md#on-scenes-and-seeds-never-trained-on-unlimited-links-studieslearned_vs_fixedpy
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from openmulti_env.environment.config import env_config
from openmulti_env.environment.reward_front import front_points
from policies import make_policy
from studies.cells import TEST_CELLS, parse_cell
from studies.episodes import env_for, episode
from studies.fronts import FIXED_RATE, margins, mean_se, paired
from studies.rows import append_row, read_rows
from studies.settings import parse_setting

INSTANCE = ("instance_novelty", "instance_novelty:change=0.1", "instance_novelty:change=1,final=0.01",
            "instance_novelty:change=1,after=999,final=0")
REFERENCE = ("at:11",)
"""Not on either front: the whole map once in the last round (rl_lite's 12 rounds), for reading the table."""


def pairs_table(rows: list[dict], pairs: list[tuple[str, str]]) -> str:
    """The paired differences of margins over the fixed-rate front, mean ± standard error over cells."""
    lines = ["| policy | minus | cells | margin difference [points] |", "|---|---|---|---|"]
    for a, b in pairs:
        d = paired(rows, a, b)
        if len(d) < 2:
            lines.append(f"| `{short_name(a)}` | `{short_name(b)}` | {len(d)} | - |")
            continue
        lines.append(f"| `{short_name(a)}` | `{short_name(b)}` | {len(d)} | {mean_se(d)} |")
    return "\n".join(lines) + "\n"


def report(rows: list[dict], learned: list[str]) -> str:
    instance_front = ("never",) + INSTANCE + ("always",)
    lines = ["| policy | cells | mean MB (of always's) | margin over the fixed-rate front [points] | "
             "margin over the instance front [points] |", "|---|---|---|---|---|"]
    between = [p for p in FIXED_RATE if p not in ("never", "always")]
    for policy in list(learned) + list(INSTANCE) + list(REFERENCE) + between:
        mine = [r for r in rows if r["policy"] == policy]
        if not mine:
            continue
        share = np.mean([r["mb"] / next(a["mb"] for a in rows if a["cell"] == r["cell"] and a["policy"] == "always")
                         for r in mine if any(a["cell"] == r["cell"] and a["policy"] == "always" for a in rows)])
        cells = []
        for family in (FIXED_RATE, instance_front):
            m = margins(rows, policy, family)
            if len(m) < 2:
                cells.append("-")
                continue
            cells.append(mean_se(m))
        lines.append(f"| `{policy}` | {len(mine)} | {np.mean([r['mb'] for r in mine]):.1f} ({100 * share:.0f} %) | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def short_name(name: str) -> str:
    """A policy file's name without the folders every run shares (``docs/schedules/learning/``, ``runs/learn/``)."""
    for prefix in ("docs/schedules/learning/", "runs/learn/"):
        if name.startswith(prefix):
            return name[len(prefix):]
    return name


def plot(rows: list[dict], learned: list[str], png: Path) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    cells = list(dict.fromkeys(r["cell"] for r in rows))
    cols = min(3, len(cells))
    fig, axes = plt.subplots(-(-len(cells) // cols), cols, figsize=(4.2 * cols, 3.4 * -(-len(cells) // cols)),
                             squeeze=False)
    for ax, cell in zip(axes.ravel(), cells):
        mine = {r["policy"]: r for r in rows if r["cell"] == cell}
        for family, colour, label in ((FIXED_RATE, "tab:gray", "fixed rate"), (("never",) + INSTANCE + ("always",),
                                                                          "tab:green", "instance_novelty")):
            pts = [(mine[p]["mb"], mine[p]["completion"]) for p in family if p in mine]
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o", color=colour, ms=3)
            kept = front_points(pts)
            ax.plot([p[0] for p in kept], [p[1] for p in kept], "-", color=colour, lw=1, label=f"{label} front")
        for k, name in enumerate(learned):
            if name in mine:
                ax.plot(mine[name]["mb"], mine[name]["completion"], "*", ms=11, color=plt.cm.tab20(k % 20),
                        label=short_name(name))
        if "at:11" in mine:
            ax.plot(mine["at:11"]["mb"], mine["at:11"]["completion"], "x", color="black", label="at:11")
        never = mine.get("never", {}).get("completion")
        ax.set_title(f"{cell}" + (f" (never: {never:.1f} %)" if never is not None else ""), fontsize=9)
        ax.set_xlabel("MB sent by the team", fontsize=8)
        ax.set_ylabel("completion %", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(cells):]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=6, loc="lower right")
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--setting", default="rl_lite")
    parser.add_argument("--cells", nargs="+", default=list(TEST_CELLS), help="SCENE:WORLD_SEED")
    parser.add_argument("--learned", nargs="*", default=[], help="policies placed against the fronts: files, "
                        "`learned`, or any policy name (e.g. a fixed-timing reference, `instance_novelty:start=9`)")
    parser.add_argument("--show", nargs="*", default=None, help="the policies the picture marks (default: every "
                        "--learned one; the table lists them all)")
    parser.add_argument("--pair", nargs=2, action="append", default=[], metavar=("A", "B"),
                        help="also report A's margin over the fixed-rate front minus B's, paired per cell (repeatable)")
    parser.add_argument("--out", default="runs/learned_vs_fixed")
    args = parser.parse_args()
    preset, overrides = parse_setting(args.setting)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows_path = out / "rows.jsonl"
    rows = read_rows(rows_path)
    done = {(r["setting"], r["cell"], r["policy"]) for r in rows}
    n = env_config(preset, **overrides).num_agents
    policies = list(FIXED_RATE) + list(INSTANCE) + list(REFERENCE) + list(args.learned)
    for cell in args.cells:
        scene, world_seed = parse_cell(cell)
        envs: dict[str, object] = {}
        for name in policies:
            if (args.setting, cell, name) in done:
                continue
            policy = make_policy(name, n, world_seed)
            env = env_for(envs, policy, preset, scene=scene, seed=world_seed, **overrides)
            row = {"setting": args.setting, "cell": cell, "policy": name, **episode(env, policy, world_seed)}
            rows.append(row)
            append_row(rows_path, row)
            print(f"{cell} {name}: {row['completion']:.2f} % {row['mb']:.1f} MB", flush=True)
        for env in envs.values():
            env.close()
    mine = [r for r in rows if r["setting"] == args.setting]
    text = (f"Setting `{args.setting}`, cells {', '.join(dict.fromkeys(r['cell'] for r in mine))}; the env's completion "
            "estimate, one episode per cell and policy; margins are paired per cell, mean ± standard error.\n\n"
            + report(mine, list(args.learned))
            + ("\nPaired, per cell (each margin against the front at its own bytes):\n\n"
               + pairs_table(mine, [tuple(p) for p in args.pair]) if args.pair else ""))
    (out / "learned_vs_fixed.md").write_text(text)
    plot(mine, list(args.learned if args.show is None else args.show), out / "fronts.png")
    print(text)


if __name__ == "__main__":
    main()
