"""One env episode of a communication policy, as the schedule studies play it.

Every schedule study compares policies on the same world and episode seed; playing them through one
function keeps the figures comparable: the env's own completion estimate (the reward's view, team
mean) and the megabytes the team sent.
"""

from __future__ import annotations

import time

import numpy as np

from openmulti_env import parallel_env


def env_for(envs: dict, policy, preset: str, **env_kwargs):
    """The env in ``policy``'s action form (``instance_novelty`` and gates over it act in ``instances``), made
    once per form and kept in ``envs``."""
    form = getattr(policy, "action_form", "entries")
    if form not in envs:
        envs[form] = parallel_env(preset=preset, **{**env_kwargs, "action_form": form})
    return envs[form]


def episode(env, policy, seed: int) -> dict[str, float | int]:
    """One episode: final completion (team mean, percent), MB sent by the team, steps, seconds per step."""
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
