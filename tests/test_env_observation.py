"""Observations come from an agent's own knowledge only: its frames, its fields, its messages."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest

from openmulti_env import parallel_env
from openmulti_env.environment.config import env_config
from openmulti_env.world.cache import cached_world
from openmulti_env.world.scene import Instance, colored_box
from openmulti_env.world.visibility import compute_observable_surface, free_space_viewpoints
from openmulti_env.environment.layout import LINK_FEATURES, MAP_CHANNELS, agent_feature, comm_size, link_feature


@pytest.fixture(scope="module")
def cache(shared_world_cache):
    return str(shared_world_cache)  # the run's one world cache: worlds other modules built are read, not built


def _with_hidden_box(world, centre):
    """The same paths in the room with one more cabinet standing at ``centre`` (its ground truth with it)."""
    scene = world.scene
    box = Instance(max(i.instance_id for i in scene.instances) + 1, "cabinet", "a small grey cabinet",
                   (0.5, 0.5, 0.5), "grey", "metal", colored_box((0.3, 0.3, 0.3), centre, (0.5, 0.5, 0.5)))
    scene = dataclasses.replace(scene, instances=[*scene.instances, box])
    surface = compute_observable_surface(scene, free_space_viewpoints(scene, world.config.free_space),
                                         max_edge_m=world.config.culling_edge_m)
    return dataclasses.replace(world, scene=scene, surface=surface, _sensor=None, _caster=None)


def _episode(env, seed=3):
    obs, _ = env.reset(seed=seed)
    trace = [obs]
    silent = {a: np.zeros(env.action_space(a).shape, np.int8) for a in env.agents}
    while env.agents:
        trace.append(env.step(dict(silent))[0])
    return trace


def test_a_world_that_differs_where_an_agent_never_looks_gives_it_the_same_observations(cache, monkeypatch):
    cfg = env_config("rl_tiny")
    world, _ = cached_world(cfg.scene, 0, cfg.world, cache)
    # a spot agent_1 sees and agent_0 never comes near: the floor point of agent_1's frames farthest (in xy)
    # from everything agent_0's frames hit
    seen = [np.concatenate([world.render(a, k).backproject(stride=2) for k in range(len(world.agent_poses[a]))])
            for a in range(2)]
    floor = seen[1][seen[1][:, 2] < 0.02]
    gap = np.min(np.linalg.norm(floor[:, None, :2] - seen[0][None, ::7, :2], axis=-1), axis=1)
    spot = floor[np.argmax(gap)]
    assert gap.max() > 0.8
    centre = spot[:2] + np.sign(np.asarray(world.scene.size_m[:2]) / 2 - spot[:2]) * 0.25
    other = _with_hidden_box(world, (*centre, 0.15))
    # the premise: agent_0's frames are the same pixels in both worlds, agent_1's are not
    for k in range(len(world.agent_poses[0])):
        a, b = world.render(0, k), other.render(0, k)
        for name in ("rgb", "depth", "instance"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert any(not np.array_equal(world.render(1, k).depth, other.render(1, k).depth)
               for k in range(len(world.agent_poses[1])))

    traces, states = [], []
    for built in (world, other):
        monkeypatch.setattr(sys.modules["openmulti_env.environment.parallel_env"], "cached_world",
                            lambda *args, w=built: (w, True))
        env = parallel_env(preset="rl_tiny", cache_dir=cache, frame_cache_mb=0)
        traces.append(_episode(env))
        states.append(env.state())
        env.close()
    first, second = traces
    assert not np.array_equal(*states)  # the ground truth (state(), rewards) differs
    assert len(first) == len(second) == 9
    for a, b in zip(first, second):
        for key in ("map", "comm"):
            np.testing.assert_array_equal(a["agent_0"][key], b["agent_0"][key])
    assert any(not np.array_equal(a["agent_1"]["map"], b["agent_1"]["map"]) for a, b in zip(first, second))


def test_the_observation_layout_and_what_it_shows(cache):
    env = parallel_env(preset="rl_tiny", cache_dir=cache)
    space = env.observation_space("agent_0")
    assert space["map"].shape == (48, 48, len(MAP_CHANNELS)) and space["map"].dtype == np.uint8
    assert space["comm"].shape == (comm_size(2),) == (len(LINK_FEATURES) + 2,)
    obs, _ = env.reset(seed=0)
    for a in env.agents:
        assert space.contains(obs[a])
        assert obs[a]["map"][..., :2].max() == 0  # nothing mapped before the first round
        np.testing.assert_array_equal(link_feature(obs[a], "since_params"), [1.0])  # never sent
    talk = {a: np.ones(env.action_space(a).shape, np.int8) for a in env.agents}
    obs, *_ = env.step(talk)
    for a in env.agents:
        m = obs[a]["map"]
        assert space.contains(obs[a])
        assert (m[..., MAP_CHANNELS.index("map_height")] > 0).mean() > 0.1  # its fields hold the floor and more
        assert m[..., MAP_CHANNELS.index("map_decided")].max() > 0
        np.testing.assert_array_equal(link_feature(obs[a], "holds"), [1.0])  # the peer got all of it
        np.testing.assert_array_equal(link_feature(obs[a], "since_params"), [0.0])
        np.testing.assert_array_equal(link_feature(obs[a], "bytes_share"), [1.0])
        assert 0 < agent_feature(obs[a], "progress") < 1
    silent = {a: np.zeros(env.action_space(a).shape, np.int8) for a in env.agents}
    for _ in range(3):
        obs, *_ = env.step(silent)
    for a in env.agents:  # its map moved on since the copy the peer holds; the copy ages
        assert link_feature(obs[a], "change")[0] > 0
        assert link_feature(obs[a], "since_params")[0] == pytest.approx(3 / 16)
    env.close()
