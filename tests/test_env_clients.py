"""Real RL clients take the env as it is: SuperSuit + Stable-Baselines3 PPO (a short run on ``tiny``) and
TorchRL's ``PettingZooWrapper`` with ``check_env_specs``. The clients come with the ``test`` extra."""

from __future__ import annotations

import numpy as np
import pytest

from openmulti_env import parallel_env


@pytest.fixture(scope="module")
def cache(shared_world_cache):
    return str(shared_world_cache)  # the run's one world cache: worlds other modules built are read, not built


def test_supersuit_and_stable_baselines3_ppo_train_on_tiny(cache):
    pytest.importorskip("supersuit")
    sb3 = pytest.importorskip("stable_baselines3")
    from policies.sb3_vec import sb3_vec_env

    vec = sb3_vec_env(parallel_env(preset="rl_tiny", cache_dir=cache))
    assert vec.num_envs == 2  # one entry per agent
    model = sb3.PPO("MultiInputPolicy", vec, n_steps=16, batch_size=16, n_epochs=1, device="cpu", verbose=0)
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.learn(total_timesteps=32)
    assert model.num_timesteps >= 32
    assert any(not np.allclose(a.numpy(), b.detach().numpy()) for a, b in zip(before, model.policy.parameters()))
    obs = vec.reset()
    actions, _ = model.predict(obs)
    assert actions.shape == (2, 2)


@pytest.mark.parametrize("episode", ["real", "recorded"])
def test_torchrl_wrapper_passes_check_env_specs(cache, episode):
    pytest.importorskip("torchrl")
    from torchrl.envs.libs.pettingzoo import PettingZooWrapper
    from torchrl.envs.utils import check_env_specs

    wrapped = PettingZooWrapper(parallel_env(preset="rl_tiny", cache_dir=cache, episode=episode, recordings=1), seed=0)
    check_env_specs(wrapped)
    rollout = wrapped.rollout(3)
    assert rollout["agent", "observation", "map"].shape[-3:] == (48, 48, 6)
    assert rollout["agent", "observation", "comm"].shape[-1] == 10
    assert rollout["next", "agent", "info", "completion_ratio"].shape == (3, 2)


class _RecordingFactory:
    """``env_factory(i)`` of the real env that remembers which world indices it was asked for."""

    def __init__(self, cache: str, odd_agents: int | None = None, **env_kwargs):
        self.cache, self.odd_agents, self.made, self.env_kwargs = cache, odd_agents, [], env_kwargs

    def __call__(self, index: int):
        self.made.append(index)
        agents = self.odd_agents if self.odd_agents and index % 2 else 2
        return parallel_env(preset="rl_tiny", num_agents=agents, cache_dir=self.cache, **self.env_kwargs)


def test_several_worlds_step_in_one_process_and_bad_sizes_are_named(cache):
    """``--worlds-per-worker``: K envs in one worker, every agent of each an entry; a world with other spaces,
    no worker, no world or more workers than cores: an error naming the problem."""
    pytest.importorskip("supersuit")
    pytest.importorskip("stable_baselines3")
    from policies.sb3_vec import check_vector_size, sb3_vec_env_from_factory

    factory = _RecordingFactory(cache)
    vec, num_agents = sb3_vec_env_from_factory(factory, workers=1, seed=3, worlds_per_worker=2)
    assert num_agents == 2 and vec.num_envs == 4 and sorted(set(factory.made)) == [0, 1]
    vec.reset()
    _, rewards, dones, infos = vec.step(np.ones((4, 2), np.int8))
    assert rewards.shape == (4,) and all("completion_ratio" in i for i in infos)
    vec.close()
    with pytest.raises(ValueError, match="world 1 .*other spaces than world 0"):
        sb3_vec_env_from_factory(_RecordingFactory(cache, odd_agents=3), workers=1, worlds_per_worker=2)
    with pytest.raises(ValueError, match="--workers must be at least 1"):
        check_vector_size(0, 1)
    with pytest.raises(ValueError, match="--worlds-per-worker must be at least 1"):
        check_vector_size(1, 0)
    with pytest.raises(ValueError, match="more worker processes than this machine's 2 cores.*--worlds-per-worker 2"):
        check_vector_size(4, 1, cores=2)


def test_many_recorded_worlds_step_in_one_process(cache):
    """Recorded episodes are light: four worlds (two recordings, two episode seeds each) step side by side in one
    SuperSuit vector env, through whole episodes and resets."""
    pytest.importorskip("supersuit")
    pytest.importorskip("stable_baselines3")
    from policies.sb3_vec import sb3_vec_env_from_factory

    factory = _RecordingFactory(cache, episode="recorded", recordings=2)
    vec, num_agents = sb3_vec_env_from_factory(factory, workers=1, seed=3, worlds_per_worker=4)
    assert num_agents == 2 and vec.num_envs == 8
    vec.reset()
    finished = 0
    for _ in range(20):  # rl_tiny episodes are 8 steps: every world ends and resets at least twice
        _, rewards, dones, infos = vec.step(np.ones((8, 2), np.int8))
        finished += int(dones.sum())
        assert np.all(np.isfinite(rewards)) and all(i["bytes_sent"] >= 0 for i in infos)
    assert finished >= 16
    vec.close()
