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

    seed_next_reset: int | None = None

    def seed(self, seed: int | None = None):
        """Seed the next reset (SuperSuit's SB3 wrapper forwards ``seed`` to vector envs that lack it)."""
        self.seed_next_reset = seed
        return [seed]

    def reset(self):
        if self.seed_next_reset is None:
            return self.venv.reset()
        inner = self.venv.venv  # SuperSuit's vector env under its SB3 wrapper: seeds entry i with seed + i
        observations, self.venv.reset_infos = inner.reset(seed=self.seed_next_reset)
        self.seed_next_reset = None
        return observations

    def step_wait(self):
        return self.venv.step_wait()


class _WorkerEnv:
    """Picklable constructor of worker ``index``'s vector env (SuperSuit ships it to its process)."""

    def __init__(self, env_factory, index: int):
        self.env_factory, self.index = env_factory, index

    def __call__(self):
        import supersuit as ss  # noqa: PLC0415

        return ss.pettingzoo_env_to_vec_env_v1(self.env_factory(self.index))


def sb3_vec_env_from_factory(env_factory, workers: int, seed: int = 0):
    """An SB3 ``VecEnv`` over ``workers`` envs, ``env_factory(i)`` each (in ``workers`` processes when more
    than one), every agent an entry; returns it with the team size. Seeded through reset (SB3's ``seed=``
    fails on SuperSuit's concatenation)."""
    from supersuit.vector import MakeCPUAsyncConstructor  # noqa: PLC0415
    from supersuit.vector.sb3_vector_wrapper import SB3VecEnvWrapper  # noqa: PLC0415

    probe = env_factory(0)
    num_agents = len(probe.possible_agents)
    spaces = probe.observation_space(probe.possible_agents[0]), probe.action_space(probe.possible_agents[0])
    probe.close()
    constructors = [_WorkerEnv(env_factory, i) for i in range(workers)]
    vec = MakeCPUAsyncConstructor(workers if workers > 1 else 0)(constructors, *spaces)
    vec = ActionCast(SB3VecEnvWrapper(vec))
    vec.seed(seed)
    return vec, num_agents
