"""A schedule made with hindsight: what an instance-level schedule could reach if it knew the episode's end.

The issue's bound: each instance's network reaches each peer once, at its final state, plus exchange every
round only for the instances two agents map. Which instances two agents map is known only once their clouds
have crossed (``shared`` in the observation), so a rule that holds everything back never learns it
(``instance_novelty:after=999``). Hindsight supplies it: a first episode sends everything (``all``, the
instance form's ``always``) and records, per agent and peer, where every instance that was ever ``shared``
lies (its box centre: ids differ between episodes); the
second episode (same world, same seed) sends a peer exactly those instances each round their copy moved by more
than ``shared`` (or the peer lacks them), rays as ``instance_novelty`` (``held``), and in the path's last round
every instance whose copy moved at all. It is a baseline that no causal policy can run, not a proof of
optimality: the headroom a learned schedule could find lies between the scripted front and it.

    .venv/bin/python -m studies.hindsight_bound --setting rl_small --rows docs/schedules/transfer/hindsight_rows.jsonl

Rows (cell, policy ``all`` / ``hindsight``, final completion, MB) are appended as each episode ends; cells as
``studies.cells.HEADROOM_CELLS`` (never used for a choice).

Figures: docs/schedules.md#at-rl_small-on-the-three-cells-never-used-for-a-choice-with-the-hindsight-bound
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from openmulti_env.environment.layout import instance_feature, link_feature
from policies.instance_novelty import last_round
from studies.cells import HEADROOM_CELLS
from studies.episodes import episode
from studies.rows import append_row, read_rows
from studies.settings import parse_setting


MATCH_M = 0.15
"""Two episodes' instances are the same object when their box centres lie this close: ids cannot be compared
across episodes (own and adopted instances draw them from one counter, and adoption differs)."""


def box_centres(env, agent: str, ids: np.ndarray) -> np.ndarray:
    """(..., 3) box centres of the agent's instances ``ids`` (NaN where an id is -1)."""
    slots = env.team.members[env.possible_agents.index(agent)].mapper.slots
    out = np.full(ids.shape + (3,), np.nan)
    for index in zip(*np.nonzero(ids >= 0)):
        bound = slots[int(ids[index])].bound
        out[index] = (np.asarray(bound.lo) + np.asarray(bound.hi)) / 2
    return out


class SendAll:
    """Every slot, every new instance, rays to every peer, every round; records the box centres of the
    instances that were ever shared, per agent and peer."""

    reads_observations, action_form = True, "instances"

    def __init__(self, env):
        self.env = env
        self.shared: dict[str, list[list[np.ndarray]]] = {}

    def __call__(self, observations, infos, step):
        actions = {}
        for agent, obs in observations.items():
            ids = self.env.slot_instance_ids(agent)
            flags = (instance_feature(obs, "shared") > 0) & (ids >= 0)
            centres = box_centres(self.env, agent, ids)
            seen = self.shared.setdefault(agent, [[] for _ in range(ids.shape[0])])
            for k in range(ids.shape[0]):
                seen[k].extend(centres[k][flags[k]])
            actions[agent] = np.ones(self.env.action_space(agent).shape, np.int8)
        return actions


class Hindsight:
    """Shared instances (known from the first episode) every round they moved; everything once at the end."""

    reads_observations, action_form = True, "instances"

    def __init__(self, env, shared: dict[str, list[list[np.ndarray]]], moved: float = 0.02):
        self.env, self.moved = env, moved
        self.shared = {a: [np.asarray(c).reshape(-1, 3) for c in per_peer] for a, per_peer in shared.items()}

    def __call__(self, observations, infos, step):
        actions = {}
        for agent, obs in observations.items():
            ids = self.env.slot_instance_ids(agent)
            present = instance_feature(obs, "present") > 0
            lacks = instance_feature(obs, "lacks") > 0
            change = instance_feature(obs, "change")
            centres = box_centres(self.env, agent, ids)  # (N-1, M, 3)
            known = np.zeros(ids.shape, bool)
            for k, recorded in enumerate(self.shared.get(agent, [])):
                if len(recorded):
                    gap = np.linalg.norm(centres[k][:, None, :] - recorded[None], axis=-1)  # (M, R), NaN: empty
                    known[k] = np.nan_to_num(gap, nan=np.inf).min(axis=1) < MATCH_M
            send = present & known & (lacks | (change > self.moved))
            final = last_round(obs, step)
            if final:
                send |= present & (lacks | (change > 0))
            new = np.full(ids.shape[0], final)
            rays = link_feature(obs, "holds") > 0
            actions[agent] = np.concatenate([send.reshape(-1), new, rays]).astype(np.int8)
        return actions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--setting", default="rl_small", help="preset[,field=value...]")
    parser.add_argument("--rows", default="docs/schedules/transfer/hindsight_rows.jsonl")
    args = parser.parse_args()
    from openmulti_env import parallel_env  # noqa: PLC0415

    rows_file = Path(args.rows)
    done = {(r["setting"], r["scene"], r["seed"]) for r in read_rows(rows_file) if r["policy"] == "hindsight"}
    preset, overrides = parse_setting(args.setting)
    for scene, seed in HEADROOM_CELLS:
        if (args.setting, scene, seed) in done:
            continue
        env = parallel_env(preset=preset, seed=seed, **{**overrides, "scene": scene, "action_form": "instances"})
        first = SendAll(env)
        results = {"all": episode(env, first, seed)}
        results["hindsight"] = episode(env, Hindsight(env, first.shared), seed)
        env.close()
        shared = {a: [len({tuple(np.round(c, 2)) for c in centres}) for centres in per_peer]
                  for a, per_peer in first.shared.items()}
        for name, result in results.items():
            row = {"setting": args.setting, "scene": scene, "seed": seed, "policy": name, **result,
                   "shared_per_peer": shared}
            append_row(rows_file, row)
            print(f"[hindsight] {scene} s{seed} {name}: {result['completion']:.2f} % {result['mb']:.1f} MB",
                      flush=True)


if __name__ == "__main__":
    main()
