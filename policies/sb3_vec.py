"""Stable-Baselines3 on a PettingZoo parallel env through SuperSuit, with the one cast the chain lacks.

``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1(base_class="stable_baselines3")`` turn every
agent into one entry of a vector env (parameter sharing). SB3 samples ``MultiBinary`` actions as float32
(Bernoulli draws), and SuperSuit's concatenation writes them into buffers of the space's dtype (int8)
with ``same_kind`` casting, which refuses (``TypeError: Cannot cast array data from dtype('float32') to
dtype('int8')``; SuperSuit 3.11, SB3 2.9). ``ActionCast`` rounds actions to the space's dtype first.
"""

from __future__ import annotations

import numpy as np


def sb3_vec_env(parallel_env, copies: int = 1, num_cpus: int = 0):
    """An SB3 ``VecEnv`` over ``copies`` x the env's agents (every agent an entry, one shared policy)."""
    import supersuit as ss  # noqa: PLC0415

    vec = ss.pettingzoo_env_to_vec_env_v1(parallel_env)
    vec = ss.concat_vec_envs_v1(vec, copies, num_cpus=num_cpus, base_class="stable_baselines3")
    return ActionCast(vec)


def _vec_env_wrapper():
    from stable_baselines3.common.vec_env import VecEnvWrapper  # noqa: PLC0415

    return VecEnvWrapper


class ActionCast(_vec_env_wrapper()):
    """Casts SB3's actions to the action space's dtype (rounding) before they reach the vector env."""

    def step_async(self, actions: np.ndarray) -> None:
        dtype = self.action_space.dtype
        if dtype is not None and np.issubdtype(dtype, np.integer):
            actions = np.rint(np.asarray(actions)).astype(dtype)
        self.venv.step_async(actions)

    def reset(self):
        return self.venv.reset()

    def step_wait(self):
        return self.venv.step_wait()
