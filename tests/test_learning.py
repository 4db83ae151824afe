"""Learning schedules: the normalised reward (never/always baselines per episode, cached), the team action form,
the centralised critic, TensorBoard logs, and worlds replayed from a fixed set of episode seeds."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from openmulti_env.environment.rewards import GAIN_FLOOR, BaselineEpisodes, step_rewards
from policies import make_policy
from policies.network import CommPolicyNetwork, NetworkConfig
from openmulti_env.environment.layout import MAP_CHANNELS, comm_size


def settings(**kw):
    base = dict(reward="team", reward_baseline="never_always", comm_cost_per_mb=0.01, comm_cost_of_always=0.3,
                budget_penalty=0.05)
    return SimpleNamespace(**{**base, **kw})


def baseline():
    never = np.array([[0, 0], [0.10, 0.20], [0.20, 0.30]])
    always = np.array([[0, 0], [0.20, 0.30], [0.60, 0.70]])
    return BaselineEpisodes(never, always, np.array([3.0, 1.0]))


def test_the_normalised_reward_pays_0_for_never_and_1_minus_the_price_for_always():
    base = baseline()
    zero = np.zeros(2)
    never = sum(step_rewards(settings(), base.never[t] - base.never[t - 1], zero, zero, t, base) for t in (1, 2))
    np.testing.assert_allclose(never, 0.0, atol=1e-12)
    always = sum(step_rewards(settings(), base.always[t] - base.always[t - 1], np.array([1.5, 0.5]), zero, t, base)
                 for t in (1, 2))
    np.testing.assert_allclose(always, 0.7)  # both steps' MB add up to always's 4 MB: the whole price
    own = sum(step_rewards(settings(reward="individual"), base.always[t] - base.always[t - 1], np.array([1.5, 0.5]),
                           zero, t, base) for t in (1, 2))
    np.testing.assert_allclose(own, [0.7, 0.7])
    flat = BaselineEpisodes(base.never, base.never + 0.001, base.always_mb)  # talking adds nothing here
    step = step_rewards(settings(), np.array([0.11, 0.21]), zero, zero, 1, flat)
    np.testing.assert_allclose(step, 0.01 / GAIN_FLOOR)  # divided by the floor, not by 0.001
    raw = step_rewards(settings(reward_baseline="none"), np.array([0.1, 0.3]), np.array([2.0, 0.0]), zero, 1, None)
    np.testing.assert_allclose(raw, 0.2 - 0.01 * 2.0 / 2)  # the raw team reward as before
    with pytest.raises(RuntimeError, match="baseline"):
        step_rewards(settings(), zero, zero, zero, 1, None)


def test_the_env_plays_each_episode_s_baselines_once_and_pays_0_for_never_and_0_7_for_always(tmp_path):
    from openmulti_env import parallel_env

    kwargs = dict(preset="rl_tiny", num_agents=2, cache_dir=str(tmp_path / "cache"), reward_baseline="never_always")
    env = parallel_env(seed=1, **kwargs)
    returns = {}
    for name, value in (("always", 1), ("never", 0)):
        env.reset(seed=7)
        total = 0.0
        while env.agents:
            _, rewards, *_ = env.step({a: np.full(2, value, np.int8) for a in env.agents})
            total += rewards["agent_0"]
        returns[name] = total
    assert env._rewarder.baselines.played == 2  # never and always, once for the episode seed
    env.close()
    assert returns["always"] == pytest.approx(0.7, abs=1e-6)  # 1 - comm_cost_of_always, whatever the world
    assert returns["never"] == pytest.approx(0.0, abs=1e-6)
    again = parallel_env(seed=1, **kwargs)
    again.reset(seed=7)
    assert again._rewarder.baselines.played == 0  # read from the disk cache
    again.close()
    with pytest.raises(ValueError, match="reward_baseline must be one of"):
        parallel_env(preset="rl_tiny", reward_baseline="mean")


def test_the_team_network_draws_one_decision_for_the_whole_team(tmp_path):
    import torch

    from policies.files import save_policy
    from policies.learned import LearnedPolicy

    torch.manual_seed(0)
    network = CommPolicyNetwork(NetworkConfig(len(MAP_CHANNELS), comm_size(3), 4, action_form="team"))
    path = save_policy(tmp_path / "team", network, 3, {"command": "test"})
    policy = make_policy(str(path), 3, seed=1)
    rng = np.random.default_rng(0)
    sent = []
    for step in range(30):
        obs = {f"agent_{i}": {"map": rng.integers(0, 255, (16, 16, len(MAP_CHANNELS)), dtype=np.uint8),
                              "comm": rng.random(comm_size(3)).astype(np.float32)} for i in range(3)}
        actions = policy(obs, None, step)
        values = np.stack(list(actions.values()))
        assert values.shape == (3, 4) and len(set(values.ravel().tolist())) == 1  # all agents, all entries alike
        sent.append(int(values[0, 0]))
    assert 0 < sum(sent) < 30  # drawn from its Bernoulli, round by round
    mode = LearnedPolicy.load(str(path), 3, seed=None)  # the mode pools the agents: their order does not matter
    shuffled = {f"agent_{i}": obs[f"agent_{k}"] for i, k in enumerate((2, 0, 1))}
    assert mode(obs)["agent_0"][0] == mode(shuffled)["agent_0"][0]


def test_the_team_gate_is_a_parallel_env_with_one_agent_that_sends_for_everyone(tmp_path):
    from pettingzoo.test import parallel_api_test

    from openmulti_env import parallel_env
    from policies.critic import WithState
    from policies.gate import TeamGate

    def gated():
        return TeamGate(WithState(parallel_env(preset="rl_tiny", num_agents=3, cache_dir=str(tmp_path / "worlds"))))

    parallel_api_test(gated(), num_cycles=4)
    env = gated()
    space = env.observation_space("team")
    assert space["map"].shape[0] == 3 and space["comm"].shape == (3, comm_size(3)) and "state" in space.spaces
    observations, _ = env.reset(seed=0)
    state = env.env.env.state()  # (S, S, 7N) -> (N, S, S, 7): agent k's planes are its 7 of state()
    assert observations["team"]["state"].shape == (3,) + state.shape[:2] + (7,) == space["state"].shape
    np.testing.assert_array_equal(observations["team"]["state"][1], state[..., 7:14])
    np.testing.assert_array_equal(observations["team"]["map"][2], state[..., 14:20])
    _, rewards, _, _, infos = env.step({"team": np.array([1])})
    assert infos["team"]["bytes_sent_total"] > 0
    _, _, _, _, infos = env.step({"team": np.array([0])})
    assert infos["team"]["bytes_sent"] == 0
    with pytest.raises(ValueError, match="one entry"):
        env.step({"team": np.array([1, 0])})


def test_the_team_gate_with_the_instance_novelty_payload_sends_what_the_rule_picks(tmp_path):
    from openmulti_env import parallel_env
    from policies.gate import TeamGate, payload_rule
    from policies.instance_novelty import InstanceNoveltyPolicy, InstanceNoveltySettings

    kwargs = dict(preset="rl_tiny", num_agents=3, cache_dir=str(tmp_path / "worlds"), action_form="instances")
    gate, alone = TeamGate(parallel_env(**kwargs), "instance_novelty:start=2"), parallel_env(**kwargs)
    seen = {}
    inner = gate.env.step

    def spy(actions):  # every agent's infos, not only the team's one
        out = inner(actions)
        seen["infos"] = out[4]
        return out

    gate.env.step = spy
    gate.reset(seed=0)
    observations, _ = alone.reset(seed=0)
    rule = InstanceNoveltyPolicy(InstanceNoveltySettings(start=2))
    for step, send in enumerate((1, 0, 1, 1)):
        gate.step({"team": np.array([send])})
        actions = rule(observations, None, step) if send else {a: np.zeros(alone.action_space(a).n, np.int8)
                                                               for a in alone.agents}
        observations, _, _, _, expected = alone.step(actions)
        got = {a: i["bytes_sent_total"] for a, i in seen["infos"].items()}
        assert got == {a: i["bytes_sent_total"] for a, i in expected.items()}
        if step < 2:  # the gate open in round 0 but the rule silent before round 2 (the gate counts rounds as runners do)
            assert sum(got.values()) == 0
    assert sum(got.values()) > 0
    # ...and less than everything: it skips what every peer already holds unchanged
    everything = TeamGate(parallel_env(**{**kwargs, "action_form": "entries"}))
    everything.reset(seed=0)
    for send in (0, 0, 1, 1):
        _, _, _, _, full = everything.step({"team": np.array([send])})
    assert seen["infos"]["agent_0"]["bytes_sent_total"] < full["team"]["bytes_sent_total"]
    with pytest.raises(ValueError, match="instances action form"):
        TeamGate(parallel_env(**{**kwargs, "action_form": "entries"}), "instance_novelty")
    with pytest.raises(ValueError, match="unknown payload"):
        payload_rule("novelty")
    with pytest.raises(ValueError, match="gates the team form only"):
        NetworkConfig(len(MAP_CHANNELS), comm_size(3), 4, action_form="round", payload="instance_novelty")


def test_a_learned_gate_over_instance_novelty_acts_in_the_instances_form(tmp_path):
    import torch

    from openmulti_env import parallel_env
    from policies.files import save_policy
    from policies.instance_novelty import InstanceNoveltyPolicy, InstanceNoveltySettings

    env = parallel_env(preset="rl_tiny", num_agents=3, cache_dir=str(tmp_path / "worlds"), action_form="instances")
    observations, _ = env.reset(seed=0)
    observations, *_ = env.step(InstanceNoveltyPolicy()(observations, None, 0))
    rule = InstanceNoveltyPolicy(InstanceNoveltySettings(start=2))
    picked = rule(observations, None, 2)
    silent = {a: np.zeros_like(v) for a, v in picked.items()}
    assert any(a.any() for a in picked.values())
    for bias, open_gate in ((10.0, True), (-10.0, False)):
        network = CommPolicyNetwork(NetworkConfig(len(MAP_CHANNELS), comm_size(3), 4, action_form="team",
                                                  payload="instance_novelty:start=2"))
        with torch.no_grad():
            network.action.weight.zero_()
            network.action.bias.fill_(bias)
        path = save_policy(tmp_path / f"gate_{bias}", network, 3, {"command": "test"})
        policy = make_policy(f"{path}:mode", 3)
        assert policy.action_form == "instances"  # runners build the env in the rule's form
        for step, expected in ((1, silent), (2, picked if open_gate else silent)):  # the runner's step reaches the rule
            actions = policy(observations, None, step)
            for agent in picked:
                np.testing.assert_array_equal(actions[agent], expected[agent])
    env.close()


@pytest.mark.parametrize("form,payload", [("team", "everything"), ("entries", "everything"),
                                          ("team", "instance_novelty")])
def test_training_with_a_central_critic_ships_a_policy_and_tensorboard_logs(tmp_path, form, payload):
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("supersuit")
    pytest.importorskip("tensorboard")
    from openmulti_env.runs.train import WorkerEnvs
    from policies.train import TrainConfig, train

    env_kwargs = {"preset": "rl_tiny", "num_agents": 3, "cache_dir": str(tmp_path / "worlds")}
    if payload != "everything":
        env_kwargs["action_form"] = "instances"
    factory = WorkerEnvs(("tiny",), workers=1, env_kwargs=env_kwargs)
    config = TrainConfig(total_env_steps=8, workers=1, n_steps=8, batch_size=8, n_epochs=1, chunk_env_steps=8,
                         action_form=form, critic="central", payload=payload)
    best = train(factory, config, tmp_path / "run", {"command": "test"}, progress=False)
    policy = make_policy(str(best), 3, seed=0)
    assert policy.record["architecture"]["action_form"] == form
    assert policy.action_form == ("entries" if payload == "everything" else "instances")
    assert policy.record["architecture"]["payload"] == payload
    if payload != "everything":  # it acts in the instances form (the training run's env)
        from openmulti_env import parallel_env

        env = parallel_env(**env_kwargs)
        observations, _ = env.reset(seed=0)
        actions = policy(observations, None, 0)
        assert all(actions[a].shape == env.action_space(a).shape for a in env.agents)
        env.close()
        with pytest.raises(ValueError, match="gates the team form"):  # refused before a run folder is claimed
            train(factory, TrainConfig(**{**config.__dict__, "action_form": "round"}), tmp_path / "other", {},
                  progress=False)
        assert not (tmp_path / "other").exists()
        return
    board = tmp_path / "run" / "tensorboard"
    assert list((board / "episodes").glob("events.out.tfevents.*")) and list((board / "ppo").glob("events.out.tfevents.*"))
    obs = {f"agent_{i}": {"map": np.zeros((16, 16, len(MAP_CHANNELS)), np.uint8),
                          "comm": np.zeros(comm_size(3), np.float32)} for i in range(3)}
    actions = np.stack(list(policy(obs, None, 0).values()))
    assert actions.shape == (3, 4)
    if form == "team":
        assert len(set(actions.ravel().tolist())) == 1
    with pytest.raises(ValueError, match="other settings"):  # a run folder keeps its critic
        train(factory, TrainConfig(**{**config.__dict__, "critic": "local"}), tmp_path / "run", {}, progress=False)


def test_the_central_critic_reads_every_agent_s_planes_in_state_order_for_any_team_size():
    import torch

    from policies.critic import StateFeatures

    torch.manual_seed(0)
    critic = StateFeatures(7 * 8, 10, 16)  # 8 agents at 48: 56 planes, more than the map's side
    state = torch.rand(2, 8, 48, 48, 7) * 255
    flat = state.permute(0, 2, 3, 1, 4).reshape(2, 48, 48, 56)  # state()'s (S, S, 7N) layout
    expected = critic.trunk(torch.cat([critic.cnn(flat.permute(0, 3, 1, 2) / 255.0),
                                       critic.comm(torch.zeros(2, 10))], dim=1))
    got = critic(dict(state=state, comm=torch.zeros(2, 10)))
    torch.testing.assert_close(got, expected)


def test_a_world_cycle_replays_its_worlds_from_a_fixed_set_of_episode_seeds(monkeypatch):
    from openmulti_env.runs import train as train_module

    seeds = []

    class Fake:
        def __init__(self, scene, **_):
            self.config = SimpleNamespace(scene=scene, env=SimpleNamespace(episode="real"))
            self.possible_agents = ["agent_0", "agent_1"]
            self.agents = ["agent_0"]

        def observation_space(self, agent):
            return None

        def action_space(self, agent):
            return None

        def reset(self, seed=None, options=None):
            seeds.append((self.config.scene, seed))
            return {}, {}

        def step(self, actions):
            return {}, {}, {}, {}, {}

        def close(self):
            pass

    monkeypatch.setattr(train_module, "OpenMultiParallelEnv", Fake)
    cycle = train_module.WorldCycle(("a", "b"), episodes_per_world=2, episode_seeds=3)
    for _ in range(8):
        cycle.reset(seed=99)
        cycle.step({})
    assert seeds == [("a", 0), ("a", 1), ("b", 0), ("b", 1), ("a", 2), ("a", 0), ("b", 2), ("b", 0)]
    with pytest.raises(ValueError, match="episode_seeds must be at least 1"):
        train_module.WorldCycle(("a",), episode_seeds=0)


@pytest.mark.parametrize("options, message", [
    (["--backend", "rllib", "--critic", "central"], "sb3 backend only"),
    (["--backend", "rllib", "--read-links", "true"], "sb3 backend only"),
    (["--critic", "both"], "unknown critic"),
    (["--payload", "instance_novelty"], "gates the team form"),
    (["--action-form", "team", "--payload", "instance_novelty", "--env.action-form", "entries"],
     "acts on the instances action form"),
    (["--action-form", "team", "--payload", "novelty"], "unknown payload"),
])
def test_training_options_that_cannot_work_are_refused_by_name(tmp_path, capsys, options, message):
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("ray.rllib")
    from openmulti_env.runs.cli import main

    code = main(["train", "--preset", "rl_tiny", "--agents", "2", "--workers", "1", "--env-steps", "8",
                 "--out", str(tmp_path / "run"), *options])
    assert code != 0 and message in capsys.readouterr().err
    assert not (tmp_path / "run" / "checkpoint.pt").exists()
