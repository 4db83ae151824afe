"""The env's behaviour beyond PettingZoo's checks: whole-episode determinism (cold and warm caches),
errors that name the problem, rewards and infos, observations, the world cache."""

from __future__ import annotations

import numpy as np
import pytest

from openmulti_env import parallel_env
from openmulti_env.environment.actions import ActionError
from openmulti_env.environment.config import FIELD_NAMES
from openmulti_env.environment import INFO_KEYS
from openmulti_env.environment.layout import MAP_CHANNELS, agent_feature
from openmulti_env.world.cache import WorldCacheWarning, clear_world_cache, world_cache_dir


@pytest.fixture(scope="module")
def cache(shared_world_cache):
    return str(shared_world_cache)  # the run's one world cache: worlds other modules built are read, not built


def _episode(e, seed: int, action_seed: int):
    obs, infos = e.reset(seed=seed)
    rng = np.random.default_rng(action_seed)
    trace = [(obs, infos)]
    while e.agents:
        actions = {a: rng.integers(0, 2, e.action_space(a).shape).astype(np.int8) for a in e.agents}
        trace.append(e.step(actions))
    return trace


def _assert_same_episode(a_trace, b_trace):
    """Every returned dict of every step equal, per agent (arrays bit for bit)."""
    assert len(a_trace) == len(b_trace)
    for a, b in zip(a_trace, b_trace):
        for x, y in zip(a, b):
            assert x.keys() == y.keys()
            for agent in x:
                if isinstance(x[agent], dict) and isinstance(next(iter(x[agent].values())), np.ndarray):
                    assert x[agent].keys() == y[agent].keys()
                    for key in x[agent]:
                        np.testing.assert_array_equal(x[agent][key], y[agent][key])
                else:
                    assert x[agent] == y[agent]


def test_same_seed_same_actions_same_episode_cold_and_warm(tmp_path):
    cold = parallel_env(preset="rl_tiny", cache_dir=str(tmp_path))
    first = _episode(cold, seed=11, action_seed=2)
    assert cold.last_cache_hit is False
    warm = parallel_env(preset="rl_tiny", cache_dir=str(tmp_path))
    second = _episode(warm, seed=11, action_seed=2)
    assert warm.last_cache_hit is True
    third = _episode(warm, seed=11, action_seed=2)  # the same env again: frames from its render cache
    assert len(first) == len(second) == len(third) == 9  # reset + 16 frames / 2 per step
    _assert_same_episode(first, second)
    _assert_same_episode(first, third)


def test_a_fleet_learner_env_plays_the_per_agent_episode(cache):
    """``learner="fleet"`` (every agent's training batched): the same episode to float tolerance."""
    apart = _episode(parallel_env(preset="rl_tiny", cache_dir=cache), seed=5, action_seed=1)
    fleet = _episode(parallel_env(preset="rl_tiny", cache_dir=cache, learner="fleet"), seed=5, action_seed=1)
    assert len(apart) == len(fleet)
    for a, b in zip(apart[1:], fleet[1:]):  # rounding may flip a probe or a voxel at its threshold: not more
        obs_a, rewards_a, *_, infos_a = a
        obs_b, rewards_b, *_, infos_b = b
        assert rewards_b == pytest.approx(rewards_a, abs=0.01)
        for agent in infos_a:
            assert infos_b[agent]["bytes_sent"] == infos_a[agent]["bytes_sent"]
            for key in obs_a[agent]:
                difference = np.abs(np.asarray(obs_b[agent][key], np.float64) - np.asarray(obs_a[agent][key]))
                assert float(np.mean(difference)) < 1e-3, key


def test_another_episode_seed_gives_another_episode(cache):
    e = parallel_env(preset="rl_tiny", cache_dir=cache)
    a = _episode(e, seed=1, action_seed=0)
    b = _episode(e, seed=2, action_seed=0)
    assert any(a[k][1]["agent_0"] != b[k][1]["agent_0"] for k in range(1, len(a)))


def test_bad_actions_name_the_agent_and_the_problem(cache):
    e = parallel_env(preset="rl_tiny", num_agents=3, cache_dir=cache)
    with pytest.raises(RuntimeError, match="reset"):
        e.step({})
    e.reset(seed=0)
    good = {a: np.zeros(4, np.int8) for a in e.agents}
    with pytest.raises(ActionError, match=r"missing \['agent_2'\]"):
        e.step({k: v for k, v in good.items() if k != "agent_2"})
    with pytest.raises(ActionError, match="unknown"):
        e.step({**good, "agent_9": np.zeros(4)})
    with pytest.raises(ActionError, match=r"agent_1: action must have shape \(4,\)"):
        e.step({**good, "agent_1": np.zeros(3)})
    with pytest.raises(ActionError, match="agent_0: action entries must be 0 or 1"):
        e.step({**good, "agent_0": np.array([0, 2, 0, 0])})
    with pytest.raises(ActionError, match="agent_0"):
        e.step({**good, "agent_0": np.array([0.5, 0, 0, 0])})
    with pytest.raises(ActionError, match="actions must be a dict \\{agent: action\\}.*got list"):
        e.step([np.zeros(4)] * 3)
    while e.agents:  # bad actions changed nothing: the episode still runs to its end
        e.step(good)
    with pytest.raises(RuntimeError, match="episode has ended"):
        e.step(good)


def test_bad_construction_is_refused_clearly(cache):
    with pytest.raises(ValueError, match="unknown preset 'huge'"):
        parallel_env(preset="huge")
    with pytest.raises(TypeError, match="unknown option 'rays_per_objekt'; did you mean rays_per_object"):
        parallel_env(preset="rl_tiny", rays_per_objekt=3)
    with pytest.raises(ValueError, match="reward must be one of"):
        parallel_env(preset="rl_tiny", reward="selfish")
    with pytest.raises(ValueError, match="num_agents must be between 2"):
        parallel_env(preset="rl_tiny", num_agents=1)
    with pytest.raises(ValueError, match="learner must be one of"):
        parallel_env(preset="rl_tiny", learner="batched")
    with pytest.raises(ValueError, match="not with run.processes"):
        parallel_env(preset="rl_tiny", learner="fleet", processes="ray")
    with pytest.raises(ValueError, match="render_mode"):
        parallel_env(preset="rl_tiny", render_mode="ascii")
    with pytest.raises(ValueError, match="unknown scene"):
        parallel_env(preset="rl_tiny", scene="castle", cache_dir=cache).reset(seed=0)
    # each refused when the env is made, not at its first reset (NaN rewards, a thread count of 0)
    for bad, message in ((dict(comm_cost_per_mb=float("nan")), "env.comm_cost_per_mb must be a finite number"),
                         (dict(budget_penalty=float("inf")), "env.budget_penalty must be a finite number"),
                         (dict(comm_budget_mb=float("nan")), "channel.budget_mb must be >= 0"),
                         (dict(threads=0), "run.threads must be None or an integer >= 1"),
                         (dict(changed_only=-1.0), "changed_only must be None or a finite number >= 0"),
                         (dict(device="tpu"), "run.device: 'tpu' is not a device")):
        with pytest.raises(ValueError, match=message):
            parallel_env(preset="rl_tiny", **bad)
    with pytest.raises(KeyError, match="unknown agent 'agent_7'"):
        parallel_env(preset="rl_tiny").observation_space("agent_7")
    assert "rays_per_object" in FIELD_NAMES


def test_infos_rewards_and_budget(cache):
    e = parallel_env(preset="rl_tiny", cache_dir=cache, comm_budget_mb=0.02, budget_penalty=0.5, reward="individual")
    obs, infos = e.reset(seed=4)
    assert all(tuple(i) == INFO_KEYS for i in infos.values())
    always = {a: np.ones(2, np.int8) for a in e.agents}
    refused_seen, total_reward = False, 0.0
    while e.agents:
        obs, rewards, _, _, infos = e.step(always)
        for a, info in infos.items():
            assert tuple(info) == INFO_KEYS and all(isinstance(v, float) and np.isfinite(v) for v in info.values())
            assert 0.0 <= info["budget_left_mb"] <= 0.02
            penalty = 0.5 * info["messages_refused"] + 0.01 * info["bytes_sent"] / 1e6  # the default price per MB
            assert rewards[a] == pytest.approx(info["completion_gain"] / 100 - penalty)
            refused_seen |= info["messages_refused"] > 0
            total_reward += rewards[a]
            assert agent_feature(obs[a], "budget_left") == pytest.approx(info["budget_left_mb"] / 0.02, abs=1e-6)
    assert refused_seen, "a 20 kB budget must run out on tiny"
    assert all(info["bytes_sent_total"] <= 0.02e6 for info in infos.values())


def test_team_reward_is_the_mean_gain_minus_shared_costs(cache):
    e = parallel_env(preset="rl_tiny", cache_dir=cache, comm_cost_per_mb=2.0)
    e.reset(seed=5)
    _, rewards, _, _, infos = e.step({a: np.ones(2, np.int8) for a in e.agents})
    gain = np.mean([i["completion_gain"] for i in infos.values()]) / 100
    mb = sum(i["bytes_sent"] for i in infos.values()) / 1e6
    assert mb > 0
    for r in rewards.values():
        assert r == pytest.approx(gain - 2.0 * mb / 2)


def test_silence_sends_nothing_and_receives_nothing(cache):
    e = parallel_env(preset="rl_tiny", cache_dir=cache)
    e.reset(seed=6)
    silent = {a: np.zeros(2, np.int8) for a in e.agents}
    while e.agents:
        obs, rewards, _, _, infos = e.step(silent)
    for a in infos:
        assert infos[a]["bytes_sent_total"] == 0 and infos[a]["instances_received"] == 0
        assert infos[a]["budget_left_mb"] == float("inf")
        assert obs[a]["map"][..., MAP_CHANNELS.index("received")].max() == 0
        assert obs[a]["map"][..., MAP_CHANNELS.index("peer_poses")].max() == 0
        assert agent_feature(obs[a], "budget_left") == 1.0
        assert infos[a]["completion_ratio"] > 5.0  # each agent maps its own part


def test_talking_fills_the_received_and_peer_channels(cache):
    e = parallel_env(preset="rl_tiny", cache_dir=cache)
    e.reset(seed=6)
    for _ in range(4):
        obs, _, _, _, infos = e.step({a: np.ones(2, np.int8) for a in e.agents})
    for a in obs:
        assert obs[a]["map"][..., MAP_CHANNELS.index("received")].max() == 255
        assert obs[a]["map"][..., MAP_CHANNELS.index("peer_poses")].max() == 255
        own = obs[a]["map"][..., MAP_CHANNELS.index("own_path")]
        assert (own == 255).sum() == 1 and (own == 128).sum() >= 1
        assert obs[a]["map"][..., MAP_CHANNELS.index("observed")].mean() > 0
        assert obs[a]["map"][..., MAP_CHANNELS.index("map_height")].max() > 0
        assert infos[a]["bytes_received"] > 0
    state = e.state()
    assert state.shape == e.state_space.shape and e.state_space.contains(state)
    np.testing.assert_array_equal(state[..., :len(MAP_CHANNELS)], obs["agent_0"]["map"])


def test_render_shows_every_agent_and_the_team_panel(cache):
    e = parallel_env(preset="rl_tiny", num_agents=3, cache_dir=cache, render_mode="rgb_array")
    e.reset(seed=0)
    e.step({a: np.ones(4, np.int8) for a in e.agents})
    img = e.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    assert img.shape[0] == 192 and img.shape[1] == 4 * 192 + 3 * 4
    assert (img[:, -192:] == (255, 225, 25)).all(-1).any()  # links used both ways this step are drawn
    plain = parallel_env(preset="rl_tiny", cache_dir=cache)
    plain.reset(seed=0)
    assert plain.render("rgb_array").shape[2] == 3  # RLlib passes the mode


def test_world_cache_corrupt_entry_is_rebuilt_with_a_warning(tmp_path):
    e = parallel_env(preset="rl_tiny", cache_dir=str(tmp_path))
    e.reset(seed=0)
    entries = list(world_cache_dir(tmp_path).glob("*.npz"))
    assert len(entries) == 1
    whole = entries[0].read_bytes()
    for broken in (b"not an npz", whole[: len(whole) // 2], whole[:-100]):  # garbage, and truncated zips
        entries[0].write_bytes(broken)
        fresh = parallel_env(preset="rl_tiny", cache_dir=str(tmp_path))
        with pytest.warns(WorldCacheWarning, match="unreadable"):
            fresh.reset(seed=0)
        assert fresh.last_cache_hit is False and entries[0].read_bytes() == whole  # rebuilt as it was
    own = world_cache_dir(tmp_path) / "my_results.npz"  # a user's file beside the entries
    own.write_bytes(b"keep me")
    assert clear_world_cache(tmp_path) == len(whole)
    assert [p.name for p in world_cache_dir(tmp_path).glob("*.npz")] == ["my_results.npz"]


def test_world_cache_key_changes_with_what_shapes_the_world(tmp_path):
    from openmulti_env.environment.config import env_config
    from openmulti_env.world.cache import world_cache_key

    base = env_config("rl_tiny")
    key = world_cache_key("tiny", 0, base.world)
    assert key == world_cache_key("tiny", 0, env_config("rl_tiny").world)
    assert key != world_cache_key("tiny", 1, base.world)
    assert key != world_cache_key("tiny", 0, env_config("rl_tiny", image_width=96).world)
    assert key != world_cache_key("room0", 0, base.world)
    # options that do not shape the world share its entry
    assert key == world_cache_key("tiny", 0, env_config("rl_tiny", rays_per_object=7).world)


def test_world_cache_is_trimmed_to_its_cap(tmp_path):
    from openmulti_env.world.cache import trim_world_cache

    import os

    names = [f"{k}" * 32 + ".npz" for k in range(3)]  # named as entries are
    for k, name in enumerate(names):
        (tmp_path / name).write_bytes(b"x" * 400_000)
        os.utime(tmp_path / name, (1000 + k, 1000 + k))  # 0 is the oldest
    (tmp_path / "results.npz").write_bytes(b"x" * 400_000)  # not an entry: never trimmed
    os.utime(tmp_path / "results.npz", (10, 10))
    trim_world_cache(tmp_path, max_mb=0.9, keep=tmp_path / names[0])
    assert sorted(p.name for p in tmp_path.glob("*.npz")) == [names[0], names[2], "results.npz"]


def test_agent_worker_threads_do_not_change_the_episode(cache):
    one = _episode(parallel_env(preset="rl_tiny", num_agents=3, cache_dir=cache, workers=1), seed=8, action_seed=3)
    two = _episode(parallel_env(preset="rl_tiny", num_agents=3, cache_dir=cache, workers=2), seed=8, action_seed=3)
    _assert_same_episode(one, two)


def test_world_cache_key_follows_a_manifests_meshes(tmp_path):
    import json

    import trimesh

    from openmulti_env.environment.config import env_config
    from openmulti_env.world.cache import world_cache_key

    trimesh.creation.box((0.5, 0.5, 0.5)).export(tmp_path / "box.obj")
    manifest = tmp_path / "room.json"
    manifest.write_text(json.dumps({"name": "r", "room": {"size_m": [3, 3, 2.5]},
                                    "objects": [{"mesh": "box.obj", "category": "box", "position_m": [1.5, 1.5]}]}))
    config = env_config("rl_tiny").world
    before = world_cache_key(str(manifest), 0, config)
    assert before == world_cache_key(str(manifest), 0, config)
    trimesh.creation.box((0.6, 0.5, 0.5)).export(tmp_path / "box.obj")  # same manifest, another mesh
    assert world_cache_key(str(manifest), 0, config) != before


def test_the_env_keeps_its_torch_threads_to_itself(cache):
    """A trainer in the same process keeps its own thread count across reset and step."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(3)
    try:
        e = parallel_env(preset="rl_tiny", cache_dir=cache, threads=1)
        e.reset(seed=0)
        assert torch.get_num_threads() == 3
        e.step({a: e.action_space(a).sample() for a in e.agents})
        assert torch.get_num_threads() == 3
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_reset_frees_the_old_team_without_a_garbage_collection(cache, workers):
    """A team holds no reference cycles: reset frees the last episode's maps by reference counting alone
    (a full garbage collection per reset cost 130 ms)."""
    import gc
    import weakref

    e = parallel_env(preset="rl_tiny", cache_dir=cache, threads=1, workers=workers)
    _episode(e, seed=2, action_seed=1)
    gone = [weakref.ref(x) for x in (e.team, *e.team.members, *(m.mapper for m in e.team.members))]
    gc.collect()
    gc.disable()
    try:
        e.reset(seed=3)
        assert all(ref() is None for ref in gone)
    finally:
        gc.enable()
