"""What a team-form policy learned: the probability that the team sends, round by round, on a few episodes.

A team policy (``--action-form team``) draws one Bernoulli a round; its return says how well the draws went, not
what the policy prefers. This plays each policy (drawn, seeded as the runners do) on each cell and records the
probability of its draw in every round, so "closed early, open late" or "open half the time everywhere" can be read
off, next to the fixed timings (``every:K``, ``instance_novelty:start=R``). Prints a table and writes
``--out/gate_probabilities.json`` and ``--out/gate_probabilities.png``.

Run: `.venv/bin/python -m studies.gate_probabilities --setting "rl_lite,link_range_m=2.5" --policies
docs/schedules/learning/gate_range_s0/latest.json --cells room1:3 office1:4 --out docs/schedules/learned_range`
(about 10 s an episode here).

Figures: docs/learning.md#links-within-25-m-a-learned-gate-over-instance_novelty---payload-instance_novelty
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mapping.pipeline.records import write_json_atomic
from openmulti_env.environment.config import env_config
from policies import make_policy
from studies.cells import HEADROOM_CELLS, parse_cell
from studies.episodes import env_for
from studies.settings import parse_setting


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--setting", default="rl_lite")
    parser.add_argument("--policies", nargs="+", required=True, help="team-form policy files")
    parser.add_argument("--cells", nargs="+", default=[f"{scene}:{seed}" for scene, seed in HEADROOM_CELLS],
                        help="SCENE:WORLD_SEED")
    parser.add_argument("--out", default="runs/gate_probabilities")
    args = parser.parse_args()
    preset, overrides = parse_setting(args.setting)
    n = env_config(preset, **overrides).num_agents
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    curves: dict[str, dict[str, list[float]]] = {}
    for name in args.policies:
        policy = make_policy(name, n, 0)
        if getattr(policy, "network", None) is None or policy.network.config.action_form != "team":
            raise SystemExit(f"{name} is not a team-form policy file: its draws are per agent or entry")
        for cell in args.cells:
            scene, world_seed = parse_cell(cell)
            policy = make_policy(name, n, world_seed)  # drawn as studies.learned_vs_fixed draws it
            env = env_for({}, policy, preset, scene=scene, seed=world_seed, **overrides)
            observations, infos = env.reset(seed=world_seed)
            probabilities, step = [], 0
            while env.agents:
                probabilities.append(policy.network.team_send_probability(*policy.inputs(observations)))
                observations, _, _, _, infos = env.step(policy(observations, infos, step))
                step += 1
            env.close()
            curves.setdefault(name, {})[cell] = probabilities
            print(f"{name} {cell}: " + " ".join(f"{p:.2f}" for p in probabilities), flush=True)
    write_json_atomic(out / "gate_probabilities.json", {"setting": args.setting, "curves": curves})

    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(7, 4))
    for k, (name, cells) in enumerate(curves.items()):
        mean = np.mean([np.asarray(p) for p in cells.values()], axis=0)
        for probabilities in cells.values():
            ax.plot(probabilities, color=f"C{k}", alpha=0.25, lw=1)
        ax.plot(mean, color=f"C{k}", lw=2, label=f"{Path(name).parent.name}/{Path(name).stem} (mean of {len(cells)} cells)")
    ax.set_xlabel("round")
    ax.set_ylabel("probability that the team sends")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(f"team gate, {args.setting}: thin lines one cell each", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "gate_probabilities.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
