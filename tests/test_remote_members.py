"""Team members as processes (``Team(processes="ray")``): one Ray actor per agent, only serialised messages
cross, and on CPU the same maps and bytes as members in one process."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

ray = pytest.importorskip("ray")

from mapping.team import ConsistencyConfig, RoundPlan, Team, TeamConfig  # noqa: E402


@pytest.fixture
def local_ray():
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    if started:
        ray.shutdown()


def _team(tiny_world, processes):
    from openmulti_env.experiment.presets import mapping_config
    from openmulti_env.world.stream import world_streams, world_vocabulary

    streams = world_streams(tiny_world, seed=0, segmentation_errors=False)
    mapping = replace(mapping_config("tiny"), iterations_per_keyframe=2, refit_steps=10)
    config = TeamConfig(mapping=mapping, frames_per_round=4, consistency=ConsistencyConfig(iterations=2, rays_per_pose=64))
    return Team(streams, config, world_vocabulary(tiny_world), seed=0, device="cpu", processes=processes)


def _maps(team: Team) -> dict:
    return {(m.index, iid): m.mapper.export_instance(iid).params for m in team.local_members()
            for iid in m.mapper.live_ids()}


def test_members_in_processes_give_the_same_maps_and_bytes(tiny_world, local_ray, tmp_path):
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as each actor runs: one thread per agent
    try:
        here = _team(tiny_world, None)
        plans = [RoundPlan.always(2), RoundPlan(np.array([[False, True], [False, False]]), np.zeros((2, 2), bool)),
                 RoundPlan.always(2)]
        expected = [here.round(plan) for plan in plans]
    finally:
        torch.set_num_threads(threads)
    apart = _team(tiny_world, "ray")
    assert all(type(m).__name__ == "RemoteMember" for m in apart.members)
    reports = [apart.round(plan) for plan in plans]
    for a, b in zip(reports, expected):
        assert a.bytes_sent == b.bytes_sent and a.delivered == b.delivered
        assert [s.instances for s in a.agents] == [s.instances for s in b.agents]
        assert [s.links for s in a.agents] == [s.links for s in b.agents]
    maps_apart, maps_here = _maps(apart), _maps(here)
    assert maps_apart.keys() == maps_here.keys() and maps_here
    for key in maps_here:
        np.testing.assert_allclose(maps_apart[key], maps_here[key], rtol=0, atol=1e-6)
    # a checkpoint of a team in processes restores into a team in this process, and the other way round
    path = apart.save(tmp_path / "team.pt")
    again = _team(tiny_world, None)
    again.load(path)
    assert again.round_index == 3 and [m.next_frame for m in again.members] == [m.next_frame for m in apart.members]
    from mapping.team.remote import start_member_processes

    with pytest.raises(ValueError, match="asks for 2 CPUs but the Ray cluster has 0 free"):
        start_member_processes(2, wait_s=0.5)  # the first team's processes still hold both CPUs
    apart.release()
    back = _team(tiny_world, "ray")
    back.load(here.save(tmp_path / "here.pt"))
    assert [m.done for m in back.members] == [m.done for m in here.members]
    assert _maps(back).keys() == maps_here.keys()
    # a restored team in processes goes on as the team in this process does (its ray messages pick mapped
    # views read before the checkpoint)
    resumed = back.round(RoundPlan.always(2))
    torch.set_num_threads(1)
    try:
        continued = here.round(RoundPlan.always(2))
    finally:
        torch.set_num_threads(threads)
    assert resumed.bytes_sent == continued.bytes_sent and resumed.delivered == continued.delivered
    for key, params in _maps(here).items():
        np.testing.assert_allclose(_maps(back)[key], params, rtol=0, atol=1e-6)


def test_processes_must_be_named():
    with pytest.raises(ValueError, match="processes must be None"):
        Team([object()], TeamConfig(), None, processes="mpi")


def test_the_env_with_agents_in_processes_steps_as_in_one(local_ray, tmp_path):
    from openmulti_env import parallel_env

    def episode(processes):
        env = parallel_env(preset="rl_tiny", processes=processes, cache_dir=str(tmp_path / "worlds"))
        observations, _ = env.reset(seed=3)
        seen = [observations]
        rewards = []
        for _ in range(2):
            observations, reward, *_ = env.step({a: np.ones(env.action_space(a).shape, np.int8) for a in env.agents})
            seen.append(observations)
            rewards.append(reward)
        env.close()
        return seen, rewards

    threads = torch.get_num_threads()
    try:
        here = episode(None)
    finally:
        torch.set_num_threads(threads)
    apart = episode("ray")
    assert apart[1] == here[1]
    for a, b in zip(apart[0], here[0]):
        for agent in b:
            assert np.array_equal(a[agent]["map"], b[agent]["map"])
            np.testing.assert_allclose(a[agent]["comm"], b[agent]["comm"], rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="run.processes must be None or 'ray', got 'mpi'"):
        parallel_env(preset="rl_tiny", processes="mpi")
