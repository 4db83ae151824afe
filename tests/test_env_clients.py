"""Real RL clients take the env as it is: SuperSuit + Stable-Baselines3 PPO (a short run on ``tiny``) and
TorchRL's ``PettingZooWrapper`` with ``check_env_specs``. The clients come with the ``test`` extra."""

from __future__ import annotations

import numpy as np
import pytest

from openmulti_env import parallel_env


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return str(tmp_path_factory.mktemp("client-worlds"))


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


def test_torchrl_wrapper_passes_check_env_specs(cache):
    pytest.importorskip("torchrl")
    from torchrl.envs.libs.pettingzoo import PettingZooWrapper
    from torchrl.envs.utils import check_env_specs

    wrapped = PettingZooWrapper(parallel_env(preset="rl_tiny", cache_dir=cache), seed=0)
    check_env_specs(wrapped)
    rollout = wrapped.rollout(3)
    assert rollout["agent", "observation", "map"].shape[-3:] == (48, 48, 6)
    assert rollout["agent", "observation", "comm"].shape[-1] == 10
    assert rollout["next", "agent", "info", "completion_ratio"].shape == (3, 2)
