"""One episode as the schedule studies play it, on a stand-in env (no world is built): what a policy is shown,
and the team's completion and megabytes."""

import pytest

import studies.episodes as episodes


class FakeEnv:
    """Three steps of two agents; completion and bytes grow each step."""

    def __init__(self, **kwargs):
        self.kwargs, self.agents, self.step_count = kwargs, [], 0

    def reset(self, seed=None):
        self.agents, self.step_count, self.seed = ["agent_0", "agent_1"], 0, seed
        return {a: "obs" for a in self.agents}, self.infos()

    def infos(self):
        return {a: {"completion_ratio": 10.0 * self.step_count + k, "bytes_sent_total": 1e6 * self.step_count}
                for k, a in enumerate(("agent_0", "agent_1"))}

    def step(self, actions):
        self.step_count += 1
        infos = self.infos()
        if self.step_count == 3:
            self.agents = []
        return {a: "obs" for a in self.agents}, {}, {}, {}, infos


class Recorder:
    def __init__(self, reads_observations):
        self.reads_observations, self.seen = reads_observations, []

    def __call__(self, observations, infos, step):
        self.seen.append((observations, step))
        return {}


@pytest.mark.parametrize("reads", [False, True])
def test_an_episode_reports_the_team_at_its_end_and_shows_observations_only_to_readers(reads):
    policy = Recorder(reads)
    result = episodes.episode(FakeEnv(), policy, seed=3)
    assert result["completion"] == pytest.approx(30.5) and result["mb"] == pytest.approx(6.0)
    assert result["steps"] == 3 and result["s_per_step"] >= 0
    assert [s for _, s in policy.seen] == [0, 1, 2]
    assert all((o is not None) == reads for o, _ in policy.seen)


def test_one_env_per_action_form(monkeypatch):
    monkeypatch.setattr(episodes, "parallel_env", FakeEnv)

    class Instances:
        action_form = "instances"

    envs = {}
    first = episodes.env_for(envs, Recorder(False), "rl_lite", scene="room1")
    assert episodes.env_for(envs, Recorder(False), "rl_lite", scene="room1") is first
    other = episodes.env_for(envs, Instances(), "rl_lite", scene="room1")
    assert other is not first and set(envs) == {"entries", "instances"}
    assert other.kwargs == {"preset": "rl_lite", "scene": "room1", "action_form": "instances"}
