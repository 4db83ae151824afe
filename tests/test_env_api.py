"""PettingZoo's own checks on the env, over a list of configurations (agents 2-6, both rewards, with and
without a budget, presets rl_tiny and rl, real and recorded episodes), plus pickling and the registry."""

from __future__ import annotations

import functools
import pickle
import types
import warnings

import numpy as np
import pytest
from pettingzoo.test import api_test, max_cycles_test, parallel_api_test, parallel_seed_test, render_test, seed_test
from pettingzoo.test.state_test import state_test

import openmulti_env
from openmulti_env import env, parallel_env, raw_env

CONFIGS = [
    dict(preset="rl_tiny", num_agents=2),
    dict(preset="rl_tiny", num_agents=3, reward="individual"),
    dict(preset="rl_tiny", num_agents=4, comm_budget_mb=0.05),
    dict(preset="rl_tiny", num_agents=6, reward="individual", comm_budget_mb=0.02, comm_cost_per_mb=0.1),
    dict(preset="rl", num_agents=4, max_cycles=2),
    dict(preset="rl_tiny", num_agents=3, action_form="instances", instance_slots=4, link_mb_per_round=0.1,
         link_range_m=3.0),
    dict(preset="rl_tiny", num_agents=2, episode="recorded", recordings=1),
    dict(preset="rl_tiny", num_agents=3, episode="recorded", recordings=2, action_form="instances", instance_slots=4,
         link_mb_per_round=0.1, link_range_m=3.0, comm_budget_mb=0.5),
]
IDS = ["rl_tiny-2", "rl_tiny-3-individual", "rl_tiny-4-budget", "rl_tiny-6-individual-budget", "rl-4",
       "rl_tiny-3-instances-links", "rl_tiny-2-recorded", "rl_tiny-3-recorded-instances-links-budget"]


@pytest.fixture(params=CONFIGS, ids=IDS)
def config(request, warm_env_kwargs):
    return warm_env_kwargs(**request.param)  # one world cache for the run, the world in it: every env hits


def test_parallel_api(config):
    parallel_api_test(parallel_env(**config), num_cycles=100)


def test_aec_api(config):
    api_test(env(**config), num_cycles=100)


def test_seeds(config):
    parallel_seed_test(functools.partial(parallel_env, **config), num_cycles=10)
    seed_test(functools.partial(env, **config), num_cycles=10)


def test_state(config):
    state_test(env(**config), parallel_env(**config), num_cycles=3)


def test_render(config):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # render_test first makes the env with render_mode="human"
        render_test(functools.partial(env, **config))


def test_max_cycles(config):
    # max_cycles_test passes max_cycles=4, which overrides a configuration's own
    module = types.SimpleNamespace(parallel_env=functools.partial(parallel_env, **config),
                                   env=functools.partial(env, **config))
    max_cycles_test(module)


def test_max_cycles_on_the_module_itself(warm_env_kwargs):
    """PettingZoo calls ``parallel_env(max_cycles=4)`` with the module's defaults (preset rl)."""
    from openmulti_env import openmulti_v0

    cache = warm_env_kwargs()["cache_dir"]
    module = types.SimpleNamespace(parallel_env=functools.partial(openmulti_v0.parallel_env, cache_dir=cache),
                                   env=functools.partial(openmulti_v0.env, cache_dir=cache))
    max_cycles_test(module)


@pytest.mark.parametrize("when", ["before reset", "after reset"])
def test_pickles(when, tmp_path):
    e = parallel_env(preset="rl_tiny", cache_dir=str(tmp_path))
    if when == "after reset":
        e.reset(seed=3)
        e.step({a: e.action_space(a).sample() for a in e.agents})
    copy = pickle.loads(pickle.dumps(e))
    obs, _ = copy.reset(seed=5)
    again, _ = parallel_env(preset="rl_tiny", cache_dir=str(tmp_path)).reset(seed=5)
    for a in obs:
        for key in obs[a]:
            np.testing.assert_array_equal(obs[a][key], again[a][key])
    aec = pickle.loads(pickle.dumps(env(preset="rl_tiny", cache_dir=str(tmp_path))))
    aec.reset(seed=1)
    assert aec.agent_selection == "agent_0"


def test_contract_names_and_registry(tmp_path):
    import pettingzoo

    assert openmulti_env.openmulti_v0.parallel_env is parallel_env
    assert openmulti_env.openmulti_v0.raw_env is raw_env
    e = pettingzoo.make("parallel", openmulti_env.ENV_ID, preset="rl_tiny", cache_dir=str(tmp_path))
    assert e.metadata["name"] == "openmulti_v0" and "rgb_array" in e.metadata["render_modes"]
    assert e.metadata["render_fps"] > 0
    assert e.possible_agents == ["agent_0", "agent_1"]
    assert e.action_space("agent_1").shape == (2,)
    aec = pettingzoo.make("aec", openmulti_env.ENV_ID, preset="rl_tiny", cache_dir=str(tmp_path))
    aec.reset(seed=0)
    assert set(aec.agents) == {"agent_0", "agent_1"}
