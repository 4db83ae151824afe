"""The recorded episode (``env.episode="recorded"``): what it replays is the real episode's, what it computes is the
real team's arithmetic, and a recording that does not fit is refused by name and made again."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from mapping.team.recorded import RecordedTeam
from mapping.team.recording import Recording, RecordingError
from openmulti_env import parallel_env
from openmulti_env.environment.recorded_episode import RecordingWarning, recording_meta, recording_path
from openmulti_env.environment.rewards import play_fixed
from openmulti_env.world.cache import clear_world_cache


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, shared_world_cache):
    """A 2-agent rl_tiny env in a recording folder of its own, reset once (the world's one recording made)."""
    from tests.conftest import warm_world_cache

    folder = tmp_path_factory.mktemp("recordings")
    warm_world_cache(preset="rl_tiny", seed=11, cache_dir=str(shared_world_cache))
    for entry in shared_world_cache.glob("*.npz"):  # the world itself from the run's cache: only recordings here
        (folder / entry.name).write_bytes(entry.read_bytes())
    env = parallel_env(preset="rl_tiny", seed=11, episode="recorded", recordings=1, cache_dir=str(folder))
    env.reset(seed=0)
    yield env
    env.close()


def play(env, schedule: str, recorded_side: bool, channel=None):
    episodes, tree = env.recorded_episodes, env.config
    recording = episodes.recording(0)
    seed = int(recording.meta["episode_seed"])
    channel = channel or tree.channel
    make = (lambda: RecordedTeam(recording, tree.team, channel, seed)) if recorded_side else \
        (lambda: episodes.real_team(seed))
    return play_fixed(make, tree.num_agents, tree.env.horizon, episodes.points, episodes.normals, schedule, seed)


def test_never_replays_the_real_episode_round_by_round(recorded):
    real, _ = play(recorded, "never", False)
    model, mb = play(recorded, "never", True)
    np.testing.assert_array_equal(model, real)  # each instance's probes, unioned, are the real map's
    assert mb.sum() == 0 and real[-1].mean() > 0.2


def test_always_costs_the_real_bytes_and_ranks_above_never(recorded):
    real, real_mb = play(recorded, "always", False)
    model, model_mb = play(recorded, "always", True)
    never, _ = play(recorded, "never", True)
    assert abs(model_mb.sum() / real_mb.sum() - 1) < 0.01  # payload sizes and headers from the real messages
    assert model[-1].mean() > never[-1].mean() + 0.05 and real[-1].mean() > never[-1].mean() + 0.05
    assert abs(model[-1].mean() - real[-1].mean()) < 0.08  # the model's error, measured in docs/recorded.md


def test_budget_capacity_and_failures_follow_the_channel_rules(recorded):
    tree = recorded.config
    budget = replace(tree.channel, budget_mb=0.3)
    _, mb = play(recorded, "always", True, budget)
    assert np.all(mb <= 0.3 + 1e-9) and mb.sum() > 0
    capped = replace(tree.channel, link_mb_per_round=0.05)
    _, mb_capped = play(recorded, "always", True, capped)
    rounds = recorded.recorded_episodes.recording(0).rounds
    assert np.all(mb_capped <= 0.05 * rounds + 1e-9)  # one link per agent at 2 agents
    lossy = replace(tree.channel, success_probability=0.0)
    seed = int(recorded.recorded_episodes.recording(0).meta["episode_seed"])
    team = RecordedTeam(recorded.recorded_episodes.recording(0), tree.team, lossy, seed)
    from mapping.team.plan import RoundPlan
    report = team.round(RoundPlan.always(2))
    assert report.delivered == 0 and report.dropped > 0 and sum(report.bytes_sent) > 0
    assert all(not s.peers for s in report.agents)  # nothing arrived: nothing held


def test_env_step_gives_the_contract_and_milliseconds(recorded):
    obs, infos = recorded.reset(seed=3)
    space = recorded.observation_space("agent_0")
    assert space.contains(obs["agent_0"])
    actions = {a: recorded.action_space(a).sample() * 0 + 1 for a in recorded.agents}
    obs, rewards, term, trunc, infos = recorded.step(actions)
    assert space.contains(obs["agent_1"]) and infos["agent_0"]["bytes_sent"] > 0
    assert infos["agent_1"]["instances_received"] > 0
    assert obs["agent_1"]["map"][..., 3].max() == 255  # the received footprints channel shows the copies
    assert recorded.recorded_episodes.made == 1  # one recording, made once, then replayed


def test_a_recording_of_another_setting_or_a_truncated_file_is_refused_by_name(recorded, tmp_path):
    episodes, tree = recorded.recorded_episodes, recorded.config
    meta = recording_meta(tree, 11, int(episodes.recording(0).meta["episode_seed"]))
    path = recording_path(tree, meta)
    assert path.exists()
    other = {**meta, "probe_points": meta["probe_points"] + 1, "version": "0.0.1"}
    with pytest.raises(RecordingError, match="probe_points: .* recorded.*version"):
        Recording.load(path, expected=other)
    cut = tmp_path / "cut.npz"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(RecordingError, match="not a whole recording"):
        Recording.load(cut)
    # the env: a truncated entry is named, made again, and the episode is the same
    before, _ = play(recorded, "every:2", True)
    path.write_bytes(path.read_bytes()[:1000])
    env = parallel_env(preset="rl_tiny", seed=11, episode="recorded", recordings=1, cache_dir=tree.env.cache_dir)
    with pytest.warns(RecordingWarning, match="not a whole recording"):
        env.reset(seed=0)
    assert env.recorded_episodes.made == 1
    after, _ = play(env, "every:2", True)
    np.testing.assert_array_equal(after, before)
    env.close()


def test_recordings_are_cleared_with_the_world_cache(tmp_path, recorded):
    folder = tmp_path / "cache"
    (folder / "recordings").mkdir(parents=True)
    (folder / "recordings" / "x-w1-e2-abc.npz").write_bytes(b"12345")
    assert clear_world_cache(folder) == 5
    assert not list((folder / "recordings").glob("*.npz"))


def test_models_it_does_not_have_are_refused(recorded):
    tree = recorded.config
    dsgd = replace(tree.team, consistency=replace(tree.team.consistency, algorithm="dsgd"))
    with pytest.raises(ValueError, match="consensus only.*dsgd"):
        RecordedTeam(recorded.recorded_episodes.recording(0), dsgd, tree.channel, 0)
    with pytest.raises(ValueError, match="episode"):
        parallel_env(preset="rl_tiny", episode="replayed")


def test_recorded_and_real_rank_schedules_alike_on_a_tiny_world(recorded):
    """Spearman over four schedules on one tiny world (docs/recorded.md has the study's cells)."""
    from scipy.stats import spearmanr

    schedules = ("never", "every:4", "every:2", "always")
    real = [play(recorded, s, False)[0][-1].mean() for s in schedules]
    model = [play(recorded, s, True)[0][-1].mean() for s in schedules]
    assert spearmanr(real, model).statistic >= 0.8
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        recorded.reset(seed=5)  # a cached recording reads back without warnings


def test_never_observations_replay_the_real_ones_bit_for_bit(recorded):
    """Every observation of a `never` episode (reset and each round): map planes from the recorded columns, frames'
    cells and poses, comm and links from the recorded snapshots, equal to the real team's."""
    from mapping.team.plan import RoundPlan
    from openmulti_env.environment.observation import team_observer

    episodes, tree = recorded.recorded_episodes, recorded.config
    recording = episodes.recording(0)
    seed, n = int(recording.meta["episode_seed"]), tree.num_agents
    size = np.asarray(recorded.world.scene.size_m, float)

    def observations(team):
        observer = team_observer(tree, size, tree.env.action_form)
        observer.reset(n)
        seen = [[observer.observe(s) for s in team.snapshots()]]
        while not team.done:
            report = team.round(RoundPlan.never(n))
            observer.update(team, report.agents)
            seen.append([observer.observe(s) for s in report.agents])
        return seen

    real, model = observations(episodes.real_team(seed)), observations(RecordedTeam(recording, tree.team, tree.channel, seed))
    assert len(real) == len(model) == recording.rounds + 1
    for step, (a, b) in enumerate(zip(real, model)):
        for agent, (x, y) in enumerate(zip(a, b)):
            for key in x:
                np.testing.assert_array_equal(x[key], y[key], err_msg=f"step {step} agent {agent} {key}")


def test_ray_messages_tell_the_real_positions_and_cost_the_real_bytes(recorded):
    """Rays only (no parameters): where each receiver believes its peers are and every byte, round by round, as the
    real team (the pose draw replayed with the real message seed)."""
    from mapping.team.plan import RoundPlan

    episodes, tree = recorded.recorded_episodes, recorded.config
    recording = episodes.recording(0)
    seed, n = int(recording.meta["episode_seed"]), tree.num_agents
    rays = RoundPlan(np.zeros((n, n), bool), ~np.eye(n, dtype=bool))
    real, model = episodes.real_team(seed), RecordedTeam(recording, tree.team, tree.channel, seed)
    while not real.done:
        a, b = real.round(rays), model.round(rays)
        assert a.bytes_sent == b.bytes_sent
        for x, y in zip(a.agents, b.agents):
            assert x.peers.keys() == y.peers.keys()
            for j in x.peers:
                assert x.peers[j].position[0] == y.peers[j].position[0]
                np.testing.assert_allclose(x.peers[j].position[1], y.peers[j].position[1], atol=1e-9)
    real.release()
