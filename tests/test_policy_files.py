"""Observation-driven and learned policies: novelty's decisions, policy files (round trip, refusals), and
training that writes a policy, its log and curve, and resumes."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from policies import PolicyError, make_policy, parse_policy
from policies.files import load_policy, policy_paths, save_policy
from policies.network import CommPolicyNetwork, NetworkConfig
from openmulti_env.environment.layout import AGE_SCALE, AGENT_FEATURES, LINK_FEATURES, MAP_CHANNELS, comm_size


def observation(num_agents=3, size=16, budget_left=1.0, progress=0.5, **links):
    """A synthetic observation: every link feature 0 unless given as a per-peer list."""
    peers = num_agents - 1
    table = np.zeros((peers, len(LINK_FEATURES)), np.float32)
    for name, values in links.items():
        table[:, LINK_FEATURES.index(name)] = values
    agent = np.array([{"budget_left": budget_left, "progress": progress}[f] for f in AGENT_FEATURES], np.float32)
    return {"map": np.zeros((size, size, len(MAP_CHANNELS)), np.uint8), "comm": np.concatenate([table.ravel(), agent])}


def test_novelty_sends_what_peers_lack_or_what_moved_and_paces_a_budget():
    policy = make_policy("novelty:change=0.1,gap=2", 3)
    assert policy.reads_observations
    lacks = observation(holds=[1.0, 0.5], change=[0.0, 0.0], since_params=[2 / AGE_SCALE, 2 / AGE_SCALE])
    np.testing.assert_array_equal(policy.act(lacks), [0, 1, 1, 1])  # rays to peers that hold my parameters
    moved = observation(holds=[1.0, 1.0], change=[0.3, 0.05], since_params=[1.0, 1.0])
    np.testing.assert_array_equal(policy.act(moved)[:2], [1, 0])
    too_soon = observation(holds=[1.0, 1.0], change=[0.3, 0.3], since_params=[0.0, 1 / AGE_SCALE])
    np.testing.assert_array_equal(policy.act(too_soon)[:2], [0, 1])  # gap=2: one round between messages
    ahead = observation(holds=[0.0, 0.0], change=[1.0, 1.0], since_params=[1.0, 1.0], budget_left=0.2, progress=0.3)
    np.testing.assert_array_equal(policy.act(ahead), [0, 0, 0, 0])  # 80 % spent at 30 % of the path
    assert make_policy("novelty:rays=never", 3).act(lacks)[2:].tolist() == [0, 0]


def test_fixed_rate_schedules():
    every = make_policy("every:3", 4)
    sends = [every(None, None, step)["agent_0"].sum() for step in range(6)]
    assert sends == [6, 0, 0, 6, 0, 0]
    at = make_policy("at:4, 0,2", 4)  # any whole rounds, in any order
    assert [at(None, None, step)["agent_3"].sum() for step in range(6)] == [6, 0, 6, 0, 6, 0]
    assert [make_policy("at:0,3", 4)(None, None, step) for step in range(4)][0]["agent_0"].tolist() == [1] * 6
    rate = [make_policy("rate:0.25", 4, seed=s)(None, None, 0) for s in (1, 1, 2)]
    assert all(np.array_equal(rate[0][a], rate[1][a]) for a in rate[0])  # seeded
    draws = np.concatenate([make_policy("rate:0.25", 4, seed=s)(None, None, 0)["agent_1"] for s in range(200)])
    assert abs(draws.mean() - 0.25) < 0.05


@pytest.mark.parametrize("bad, message", [("every:0", "K >= 1"), ("rate:1.5", "Q in \\[0, 1\\]"),
                                          ("at:1,-2", "rounds as whole numbers >= 0"), ("at:1;2", "separated by commas"),
                                          ("novelty:speed=2", "name=value pairs"), ("novelty:rays=maybe", "rays must"),
                                          ("novelty:change=nan", "change and slack finite"),
                                          ("novelty:slack=inf", "change and slack finite"),
                                          ("novelty:gap=x", "novelty"), ("bernoulli:nan", "\\[0, 1\\]"),
                                          ("sometimes", "unknown policy"), ("runs/x/best.json", "does not exist"),
                                          ("runs/x/best.json:mode", "file .runs/x/best.json. does not exist")])
def test_bad_policy_names_say_what_is_wrong(bad, message):
    with pytest.raises(PolicyError, match=message):
        parse_policy(bad)


def _network(num_agents=3, seed=0):
    torch = pytest.importorskip("torch")
    torch.manual_seed(seed)
    return CommPolicyNetwork(NetworkConfig(len(MAP_CHANNELS), comm_size(num_agents), 2 * (num_agents - 1)))


def test_policy_files_round_trip_and_refuse_what_does_not_fit(tmp_path):
    network = _network()
    path = save_policy(tmp_path / "p", network, 3, {"command": "test"})
    assert policy_paths(path) == (tmp_path / "p.json", tmp_path / "p.safetensors")
    umask = os.umask(0)
    os.umask(umask)
    assert all(part.stat().st_mode & 0o777 == 0o666 & ~umask for part in policy_paths(path))  # not mkstemp's 0600
    rng = np.random.default_rng(0)
    obs = {f"agent_{i}": {"map": rng.integers(0, 256, (16, 16, len(MAP_CHANNELS)), dtype=np.uint8),
                          "comm": rng.random(comm_size(3)).astype(np.float32)} for i in range(3)}
    maps, comms = np.stack([o["map"] for o in obs.values()]), np.stack([o["comm"] for o in obs.values()])
    # ':mode' is each entry's mode; the file itself draws each entry as trained, seeded
    mode = make_policy(f"{path}:mode", 3)(obs, None, 0)
    assert all(np.array_equal(mode[f"agent_{i}"], network.act(maps, comms)[i]) for i in range(3))
    drawn = make_policy(str(path), 3, seed=5)(obs, None, 0)
    again = network.act(maps, comms, np.random.default_rng(5))
    assert all(np.array_equal(drawn[f"agent_{i}"], again[i]) for i in range(3))
    torch = pytest.importorskip("torch")
    with torch.no_grad():
        probs = torch.sigmoid(network.action(network.features.observe(maps, comms))).numpy()
    policy = make_policy(str(path), 3, seed=1)
    mean = np.mean([np.stack(list(policy(obs, None, t).values())) for t in range(400)], axis=0)
    np.testing.assert_allclose(mean, probs, atol=0.1)  # the draws follow the network's probabilities
    with pytest.raises(PolicyError, match="for 3 agents; the team has 4"):
        make_policy(str(path), 4)
    record = json.loads(path.read_text())
    other = {**record, "observation": {**record["observation"], "map_channels": ["height"]}}
    (tmp_path / "layout.json").write_text(json.dumps(other))
    (tmp_path / "layout.safetensors").write_bytes((tmp_path / "p.safetensors").read_bytes())
    with pytest.raises(PolicyError, match="another observation layout"):
        load_policy(tmp_path / "layout.json")
    blob = (tmp_path / "p.safetensors").read_bytes()
    (tmp_path / "p.safetensors").write_bytes(blob[:len(blob) // 2])
    with pytest.raises(PolicyError, match="changed or truncated"):
        load_policy(path)
    (tmp_path / "p.safetensors").write_bytes(blob[:-1] + bytes([blob[-1] ^ 1]))
    with pytest.raises(PolicyError, match="changed or truncated"):
        load_policy(path)
    path.write_text(path.read_text()[:40])
    with pytest.raises(PolicyError, match="not valid JSON"):
        load_policy(path)
    (tmp_path / "p.json").unlink()
    with pytest.raises(PolicyError, match="is missing"):
        load_policy(tmp_path / "p.safetensors")


def test_training_writes_a_policy_a_log_and_a_curve_and_resumes(tmp_path):
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("supersuit")
    from openmulti_env.runs.train import WorkerEnvs
    from policies.train import TrainConfig, train

    factory = WorkerEnvs(("tiny",), workers=1, env_kwargs={"preset": "rl_tiny", "comm_cost_per_mb": 0.01,
                                                            "cache_dir": str(tmp_path / "worlds")})
    config = TrainConfig(total_env_steps=16, workers=1, n_steps=8, batch_size=16, n_epochs=1, chunk_env_steps=8)
    best = train(factory, config, tmp_path / "run", {"command": "test"}, progress=False)
    rows = (tmp_path / "run" / "log.csv").read_text().splitlines()
    assert rows[0] == "env_steps,worker,return,completion,mb" and len(rows) == 3  # two 8-step episodes
    completion = float(rows[1].split(",")[3])
    assert 0 < completion < 100
    assert (tmp_path / "run" / "learning_curve.png").stat().st_size > 0
    policy = make_policy(str(best), 2)
    assert policy.record["training"]["env_steps"] == 16
    train(factory, TrainConfig(**{**config.__dict__, "total_env_steps": 24}), tmp_path / "run", {"command": "test"},
          progress=False)
    assert json.loads((tmp_path / "run" / "latest.json").read_text())["training"]["env_steps"] == 24
    with pytest.raises(ValueError, match="other settings"):
        train(factory, TrainConfig(**{**config.__dict__, "learning_rate": 1.0}), tmp_path / "run", {}, progress=False)


def test_the_shipped_policy_loads_acts_for_four_agents_and_refuses_other_teams(tmp_path):
    pytest.importorskip("torch")
    from openmulti_env import parallel_env
    from policies.learned import SHIPPED

    assert SHIPPED.is_file() and SHIPPED.with_suffix(".safetensors").is_file()
    policy = make_policy("learned", 4, seed=0)
    assert policy.record["num_agents"] == 4 and "openmulti train" in policy.record["training"]["command"]
    env = parallel_env(preset="rl_tiny", num_agents=4, cache_dir=str(tmp_path / "worlds"),
                       action_form=policy.action_form)  # the form it acts in (a gate over a rule: instances)
    observations, infos = env.reset(seed=0)
    for step in range(3):
        actions = policy(observations, infos, step)
        assert set(actions) == set(observations)
        assert all(a.shape == env.action_space(name).shape and set(a.tolist()) <= {0, 1} for name, a in actions.items())
        observations, _, _, _, infos = env.step(actions)
    env.close()
    with pytest.raises(PolicyError, match="for 4 agents; the team has 3"):
        make_policy("learned", 3)


def test_the_round_form_draws_one_decision_per_agent_and_round_trips(tmp_path):
    torch = pytest.importorskip("torch")
    torch.manual_seed(0)
    network = CommPolicyNetwork(NetworkConfig(len(MAP_CHANNELS), comm_size(3), 4, action_form="round"))
    assert network.action.out_features == 1
    rng = np.random.default_rng(0)
    maps = rng.integers(0, 256, (3, 16, 16, len(MAP_CHANNELS)), dtype=np.uint8)
    comms = rng.random((3, comm_size(3))).astype(np.float32)
    drawn = np.stack([network.act(maps, comms, np.random.default_rng(s)) for s in range(300)])
    assert drawn.shape == (300, 3, 4) and np.all(drawn == drawn[..., :1])  # every entry of an agent: one draw
    with torch.no_grad():
        probs = torch.sigmoid(network.action(network.features.observe(maps, comms))).numpy()[:, 0]
    np.testing.assert_allclose(drawn[..., 0].mean(axis=0), probs, atol=0.1)
    path = save_policy(tmp_path / "round", network, 3, {"command": "test"})
    loaded, record = load_policy(path, 3)
    assert record["architecture"]["action_form"] == "round" and loaded.config == network.config
    np.testing.assert_array_equal(loaded.act(maps, comms), network.act(maps, comms))
    entries = {**record, "architecture": {k: v for k, v in record["architecture"].items() if k != "action_form"}}
    assert NetworkConfig.from_dict(entries["architecture"]).action_form == "entries"  # files from before the form
    bad = {**record, "architecture": {**record["architecture"], "action_form": "peers"}}
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    (tmp_path / "bad.safetensors").write_bytes((tmp_path / "round.safetensors").read_bytes())
    with pytest.raises(PolicyError, match="unknown action form 'peers'"):
        load_policy(tmp_path / "bad.json")


def test_a_crafted_architecture_is_refused_before_anything_of_its_size_is_built(tmp_path, monkeypatch):
    import policies.files as files

    network = CommPolicyNetwork(NetworkConfig(len(MAP_CHANNELS), comm_size(3), 4))
    path = save_policy(tmp_path / "small", network, 3, {"command": "test"})
    record = json.loads(path.read_text())
    huge = {**record, "architecture": {**record["architecture"], "features": 20_000, "map_features": 20_000,
                                        "comm_features": 20_000}}
    (tmp_path / "huge.json").write_text(json.dumps(huge))
    (tmp_path / "huge.safetensors").write_bytes((tmp_path / "small.safetensors").read_bytes())
    built = []

    class Watched(files.CommPolicyNetwork):
        def __init__(self, config):
            super().__init__(config)
            built.append(next(self.parameters()).device.type)

    monkeypatch.setattr(files, "CommPolicyNetwork", Watched)
    with pytest.raises(PolicyError, match="do not fit the recorded architecture.*tensors"):
        load_policy(tmp_path / "huge.json")
    assert built == ["meta"]  # only its shapes: 20,000-wide layers would take about 1.8 GB
    assert load_policy(path)[1]["num_agents"] == 3 and built == ["meta", "meta", "cpu"]  # a fitting file: built


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_weights_are_refused_even_with_a_recomputed_hash(tmp_path, bad):
    import hashlib
    import re

    from safetensors.torch import save

    network = _network()
    path = save_policy(tmp_path / "p", network, 3, {"command": "test"})
    weights = {k: v.clone() for k, v in network.state_dict().items()}
    weights["features.trunk.0.bias"][5] = bad
    blob = save(weights)
    (tmp_path / "p.safetensors").write_bytes(blob)
    path.write_text(json.dumps({**json.loads(path.read_text()), "sha256": hashlib.sha256(blob).hexdigest()}))
    network.load_state_dict(weights)  # what loading it would give: with NaN every logit NaN, and that never sends
    sends = network.act(np.zeros((3, 16, 16, len(MAP_CHANNELS)), np.uint8), np.zeros((3, comm_size(3))))
    assert not (np.isnan(bad) and sends.any())
    with pytest.raises(PolicyError, match=re.escape(str(tmp_path / "p.safetensors")) +
                       ".*tensor 'features.trunk.0.bias' holds 1 non-finite value.*NaN or inf"):
        load_policy(path)


def test_an_observation_version_that_does_not_exist_is_refused(tmp_path):
    path = save_policy(tmp_path / "p", _network(), 3, {"command": "test"})
    record = json.loads(path.read_text())
    for version, what in ((99, "unknown"), ("banana", "not a whole number"), (True, "not a whole number")):
        path.write_text(json.dumps({**record, "observation_version": version}))
        with pytest.raises(PolicyError, match=f"{path}.* records observation_version {version!r}, {what}.*this "
                                              "release reads observation versions 1, 2"):
            load_policy(path)
    path.write_text(json.dumps({k: v for k, v in record.items() if k != "observation_version"}))
    assert load_policy(path)[1]["num_agents"] == 3  # written before the version was recorded: version 1


def test_an_oversized_or_deeply_nested_policy_json_is_refused_before_it_is_read_or_parsed(tmp_path, monkeypatch):
    from pathlib import Path

    import policies.files as files

    path = save_policy(tmp_path / "p", _network(), 3, {"command": "test"})
    record = json.loads(path.read_text())
    (tmp_path / "big.safetensors").write_bytes((tmp_path / "p.safetensors").read_bytes())
    with (tmp_path / "big.json").open("wb") as f:
        f.truncate(files.MAX_JSON_BYTES + 1)  # sparse: nothing written
    with monkeypatch.context() as patch:
        patch.setattr(Path, "open", lambda *a, **k: pytest.fail("the oversized JSON was opened"))
        with pytest.raises(PolicyError, match=f"{tmp_path / 'big.json'} is 1,048,577 bytes, over the 1,048,576"):
            load_policy(tmp_path / "big.json")
    path.write_text('{"format": ' + "[" * 100_000 + "]" * 100_000 + "}")  # json.loads: RecursionError
    with pytest.raises(PolicyError, match=f"{path} nests objects and arrays more than 32 deep"):
        load_policy(path)
    path.write_text(json.dumps({**record, "training": {"command": "[{" * 100_000}}))  # brackets in a string
    assert load_policy(path)[1]["training"]["command"].startswith("[{[{")


def test_the_round_gate_is_a_parallel_env_that_sends_everything_or_nothing(tmp_path):
    from pettingzoo.test import parallel_api_test

    from openmulti_env import parallel_env
    from policies.gate import RoundGate

    def gated():
        return RoundGate(parallel_env(preset="rl_tiny", num_agents=3, cache_dir=str(tmp_path / "worlds")))

    parallel_api_test(gated(), num_cycles=10)
    env = gated()
    assert env.action_space("agent_0").n == 1
    env.reset(seed=0)
    *_, infos = env.step({"agent_0": np.array([1]), "agent_1": np.array([0]), "agent_2": np.array([0])})
    assert infos["agent_0"]["bytes_sent_total"] > 0
    assert infos["agent_1"]["bytes_sent_total"] == 0 == infos["agent_2"]["bytes_sent_total"]
    with pytest.raises(ValueError, match="agent_1: a round-form action is one entry"):
        env.step({"agent_0": np.array([1]), "agent_1": np.array([1, 0, 1, 0]), "agent_2": np.array([0])})


def test_training_in_the_round_form_ships_a_policy_that_sends_all_or_nothing(tmp_path):
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("supersuit")
    from openmulti_env.runs.train import WorkerEnvs
    from policies.train import TrainConfig, train

    factory = WorkerEnvs(("tiny",), workers=1, env_kwargs={"preset": "rl_tiny", "num_agents": 3,
                                                            "cache_dir": str(tmp_path / "worlds")})
    config = TrainConfig(total_env_steps=8, workers=1, n_steps=8, batch_size=24, n_epochs=1, chunk_env_steps=8,
                         action_form="round")
    best = train(factory, config, tmp_path / "run", {"command": "test"}, progress=False)
    policy = make_policy(str(best), 3, seed=0)
    assert policy.record["architecture"]["action_form"] == "round"
    obs = {f"agent_{i}": observation(3) for i in range(3)}
    for step in range(20):
        assert all(len(set(a.tolist())) == 1 and a.shape == (4,) for a in policy(obs, None, step).values())
    with pytest.raises(ValueError, match="other settings"):  # a run folder keeps its action form
        train(factory, TrainConfig(**{**config.__dict__, "action_form": "entries"}), tmp_path / "run", {},
              progress=False)


class _RunsCode:
    """What a crafted checkpoint carries: unpickling it calls ``Path.touch`` on a marker file."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        from pathlib import Path

        return Path.touch, (Path(self.marker),)


def test_training_checkpoints_never_run_code_on_resume(tmp_path):
    torch = pytest.importorskip("torch")
    from policies.safe_checkpoint import (UnsafeCheckpointError, load_training_state, refuse_pickled_checkpoint,
                                          refuse_pickled_rllib_checkpoint, save_training_state, tensors_only)

    state = {"policy": {"w": torch.arange(6.0).reshape(2, 3)}, "policy.optimizer": {"param_groups": [{"lr": 3e-4}]}}
    save_training_state(tmp_path / "checkpoint.pt", state, {"num_timesteps": 32, "n_updates": 4})
    back, counters = load_training_state(tmp_path / "checkpoint.pt")
    assert torch.equal(back["policy"]["w"], state["policy"]["w"]) and counters == {"num_timesteps": 32, "n_updates": 4}
    marker = tmp_path / "ran"
    torch.save({"format": "openmulti.training-checkpoint", "version": 1, "counters": {},
                "state": _RunsCode(str(marker))}, tmp_path / "crafted.pt")
    torch.load(tmp_path / "crafted.pt", weights_only=False)  # what a pickle load would do: the payload runs
    assert marker.exists()
    marker.unlink()
    with pytest.raises(UnsafeCheckpointError, match="objects other than tensors.*could run code.*start again"):
        load_training_state(tmp_path / "crafted.pt")
    assert not marker.exists()
    (tmp_path / "checkpoint.zip").write_bytes(b"PK\x03\x04 an older release's SB3 checkpoint")
    with pytest.raises(UnsafeCheckpointError, match="pickled SB3 checkpoint.*not read.*checkpoint.pt"):
        refuse_pickled_checkpoint(tmp_path / "checkpoint.zip")
    (tmp_path / "truncated.pt").write_bytes((tmp_path / "checkpoint.pt").read_bytes()[:100])
    with pytest.raises(UnsafeCheckpointError, match="corrupt or truncated"):
        load_training_state(tmp_path / "truncated.pt")

    # RLlib's own checkpoint folders restore by unpickling: an older release's is refused, never read
    (tmp_path / "checkpoint").mkdir()
    (tmp_path / "checkpoint" / "algorithm_state.pkl").write_bytes(b"pickled state")
    with pytest.raises(UnsafeCheckpointError, match="RLlib checkpoint folder.*could run code.*checkpoint.pt"):
        refuse_pickled_rllib_checkpoint(tmp_path / "checkpoint")
    # what RLlib hands over (NumPy arrays and scalars) is saved as tensors and numbers; any other object is refused
    learner = {"optimizer": {"default": {"module_id": "shared", "state": {"state": {0: {"step": np.array(3.0)}},
                                                                       "param_groups": [{"betas": (0.9, 0.999)}]}}}}
    converted = tensors_only(learner)
    assert torch.equal(converted["optimizer"]["default"]["state"]["state"][0]["step"], torch.tensor(3.0, dtype=torch.float64))
    assert tensors_only({"lr": np.float32(0.5)}) == {"lr": 0.5}
    with pytest.raises(ValueError, match=r"state\['callback'\] is a _RunsCode"):
        tensors_only({"callback": _RunsCode(str(marker))})
    # the temporary file is made new: a symlink planted under its name is replaced, its target left alone
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    planted = tmp_path / f".checkpoint.pt.{os.getpid()}.tmp"
    planted.symlink_to(victim)
    save_training_state(tmp_path / "checkpoint.pt", state, {"num_timesteps": 1, "n_updates": 1})
    assert victim.read_text() == "keep me" and not planted.exists()
    assert load_training_state(tmp_path / "checkpoint.pt")[1] == {"num_timesteps": 1, "n_updates": 1}


def test_a_training_folder_made_before_worlds_per_worker_still_resumes():
    """``same_run`` fills in the settings added after runs were made (``action_form``, ``worlds_per_worker``) at
    the behaviour from before them; another value is another run."""
    from dataclasses import asdict

    from policies.train import TrainConfig, same_run

    now = {"train": asdict(TrainConfig(workers=1)), "command": "openmulti train --workers 1"}
    before = {"train": {k: v for k, v in now["train"].items() if k not in ("worlds_per_worker", "action_form")},
              "command": "an older command line"}
    assert same_run(before, now)
    assert not same_run(before, {**now, "train": {**now["train"], "worlds_per_worker": 2}})


def test_training_envs_share_the_cores_among_worker_processes_without_changing_the_run(tmp_path, monkeypatch):
    """Each worker's env takes cores / workers agent threads (two processes of two threads each kept four
    threads on two cores); the setting changes speed only, so it stays out of the run's identity."""
    import policies.train
    from mapping.runtime import available_cores
    from openmulti_env.runs.cli import main

    seen = {}

    def fake_train(factory, config, out, record, progress=True):
        seen.update(factory=factory, record=record, config=config)
        return tmp_path / "best.json"

    monkeypatch.setattr(policies.train, "train", fake_train)
    assert main(["train", "--preset", "rl_tiny", "--agents", "2", "--workers", "1", "--env-steps", "8",
                 "--scenes", "tiny", "--out", str(tmp_path / "t")]) == 0
    assert seen["factory"].env_kwargs["run__workers"] == max(1, available_cores() // seen["config"].workers)
    assert "run__workers" not in json.dumps(seen["record"]["env"])
