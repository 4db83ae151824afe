"""Stable-Baselines3 on a PettingZoo parallel env through SuperSuit, with the one cast the chain lacks.

``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1(base_class="stable_baselines3")`` turn every
agent into one entry of a vector env (parameter sharing). SB3 samples ``MultiBinary`` actions as float32
(Bernoulli draws), and SuperSuit's concatenation writes them into buffers of the space's dtype (int8)
with ``same_kind`` casting, which refuses (``TypeError: Cannot cast array data from dtype('float32') to
dtype('int8')``; SuperSuit 3.11, SB3 2.9). ``ActionCast`` rounds actions to the space's dtype first.
"""

from __future__ import annotations

import os

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
    """Picklable constructor of world ``index``'s vector env (SuperSuit ships it to its worker process)."""

    def __init__(self, env_factory, index: int):
        self.env_factory, self.index = env_factory, index

    def __call__(self):
        import supersuit as ss  # noqa: PLC0415

        return ss.pettingzoo_env_to_vec_env_v1(self.env_factory(self.index))


def _spaces(env) -> tuple:
    first = env.possible_agents[0]
    return env.observation_space(first), env.action_space(first)


def check_vector_size(workers: int, worlds_per_worker: int, cores: int | None = None) -> None:
    """ValueError naming the problem: no worker or world, or more worker processes than cores."""
    cores = cores or (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()) or 1
    if workers < 1:
        raise ValueError(f"--workers must be at least 1 (1: this process), got {workers}")
    if worlds_per_worker < 1:
        raise ValueError(f"--worlds-per-worker must be at least 1, got {worlds_per_worker}")
    if workers > cores:
        raise ValueError(f"--workers {workers} asks for more worker processes than this machine's {cores} cores; "
                         f"use --workers {cores} and --worlds-per-worker {-(-workers * worlds_per_worker // cores)} "
                         "for as many worlds")


def sb3_vec_env_from_factory(env_factory, workers: int, seed: int = 0, worlds_per_worker: int = 1):
    """An SB3 ``VecEnv`` over ``workers`` x ``worlds_per_worker`` envs, ``env_factory(i)`` each (``workers``
    processes when more than one, each stepping its worlds in turn), every agent an entry; returns it with the
    team size. Seeded through reset (SB3's ``seed=`` fails on SuperSuit's concatenation)."""
    from supersuit.vector import MakeCPUAsyncConstructor  # noqa: PLC0415
    from supersuit.vector.sb3_vector_wrapper import SB3VecEnvWrapper  # noqa: PLC0415

    check_vector_size(workers, worlds_per_worker)
    probe = env_factory(0)
    num_agents, spaces = len(probe.possible_agents), _spaces(probe)
    probe.close()
    for index in range(1, workers * worlds_per_worker):  # every entry shares one policy: refuse here, not in a worker
        env = env_factory(index)
        other = _spaces(env)
        scene = getattr(env, "scene", "?")
        env.close()
        if other != spaces:
            raise ValueError(f"world {index} ({scene}) has other spaces than world 0 (observation {other[0]}, action "
                             f"{other[1]}; world 0: {spaces[0]}, {spaces[1]}): every world of a vector env needs the "
                             "same preset and team size")
    constructors = [_WorkerEnv(env_factory, i) for i in range(workers * worlds_per_worker)]
    vec = MakeCPUAsyncConstructor(workers if workers > 1 else 0)(constructors, *spaces)
    vec = ActionCast(SB3VecEnvWrapper(vec))
    vec.seed(seed)
    return vec, num_agents
