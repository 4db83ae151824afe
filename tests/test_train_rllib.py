"""``openmulti train --backend rllib``: RLlib's multi-agent PPO with the package's network, run folder and
policy files."""

from __future__ import annotations

import json
import pickle
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("ray.rllib")
torch = pytest.importorskip("torch")

from gymnasium import spaces  # noqa: E402

from policies import make_policy  # noqa: E402
from policies.safe_checkpoint import UnsafeCheckpointError, tensors_only  # noqa: E402
from openmulti_env.environment.layout import MAP_CHANNELS, comm_size  # noqa: E402


def _module(actions: int = 6, agents: int = 4):
    from policies.network import NetworkConfig
    from policies.rllib_module import CommRLModule

    space = spaces.Dict({"map": spaces.Box(0, 255, (48, 48, len(MAP_CHANNELS)), np.uint8),
                         "comm": spaces.Box(0.0, 1.0, (comm_size(agents),), np.float32)})
    config = NetworkConfig(map_channels=len(MAP_CHANNELS), comm_size=comm_size(agents), actions=6).as_dict()
    return CommRLModule(observation_space=space, action_space=spaces.MultiBinary(actions),
                        model_config={**config, "vf_share_layers": True}), space  # RLlib adds keys of its own


def test_the_rllib_module_exports_to_the_same_policy_and_draws_bernoulli_entries():
    from ray.rllib.core.columns import Columns

    from policies.rllib_module import BernoulliEntries, export_module

    torch.manual_seed(0)
    module, space = _module()
    space.seed(0)
    batch = [space.sample() for _ in range(5)]
    obs = {key: torch.as_tensor(np.stack([b[key] for b in batch])) for key in ("map", "comm")}
    logits = module.forward_inference({Columns.OBS: obs})[Columns.ACTION_DIST_INPUTS]
    network = export_module(module)
    exported = network.action(network.features.observe(obs["map"].numpy(), obs["comm"].numpy()))
    torch.testing.assert_close(exported, logits)  # what RLlib acts on is what the policy file acts on
    assert np.array_equal(network.act(obs["map"].numpy(), obs["comm"].numpy()), (logits > 0).numpy())
    values = module.compute_values({Columns.OBS: obs})
    assert values.shape == (5,) and torch.isfinite(values).all()

    dist = BernoulliEntries.from_logits(logits)
    draw = dist.sample()
    assert draw.shape == (5, 6) and set(draw.unique().tolist()) <= {0.0, 1.0}
    per_entry = torch.distributions.Bernoulli(logits=logits).log_prob(draw).sum(-1)
    torch.testing.assert_close(dist.logp(draw), per_entry)
    assert torch.equal(dist.to_deterministic().sample(), (logits > 0).float())
    with pytest.raises(ValueError, match="6 action entries but the env's action space"):
        _module(actions=4)


def test_one_rllib_iteration_on_two_env_runners_logs_exports_and_resumes(tmp_path, monkeypatch):
    from openmulti_env.runs.train import WorkerEnvs
    from policies.train import TrainConfig
    from policies.train_rllib import train_rllib

    factory = WorkerEnvs(("tiny",), workers=2, env_kwargs={"preset": "rl_tiny", "comm_cost_per_mb": 0.01,
                                                            "cache_dir": str(tmp_path / "worlds")})
    # 6 rounds per runner and iteration against 8-step episodes: every episode is cut across two samples
    config = TrainConfig(total_env_steps=24, workers=2, n_steps=6, batch_size=8, n_epochs=1, chunk_env_steps=24)
    best = train_rllib(factory, config, tmp_path / "run", {"command": "test"}, progress=False)
    rows = (tmp_path / "run" / "log.csv").read_text().splitlines()
    assert rows[0] == "env_steps,worker,return,completion,mb"
    assert sorted(int(r.split(",")[1]) for r in rows[1:]) == [0, 1]  # one 8-step episode on each runner
    for row in rows[1:]:
        episode_return, completion, mb = (float(v) for v in row.split(",")[2:5])
        assert 0 < completion < 100 and mb > 0
        # the team reward sums to the final completion less the cost of the team's MB per agent: the whole
        # episode's return, not its last chunk's
        assert episode_return == pytest.approx(completion / 100 - 0.01 * mb / 2, abs=1e-4)
    assert (tmp_path / "run" / "learning_curve.png").stat().st_size > 0
    policy = make_policy(str(best), 2, seed=0)
    assert policy.record["training"]["backend"] == "rllib" and policy.record["training"]["env_steps"] == 24

    # resuming rebuilds the algorithm and puts the checkpoint's tensors into it; pickles anywhere in the run folder
    # (RLlib's own names, a symlinked folder) are never read
    import policies.train_rllib as train_module

    marker, restored = tmp_path / "ran", []
    for name in ("algorithm_state.pkl", "learner_group/learner/state.pkl", "env_runner/state.pkl",
                 "learner_group/learner/rl_module/shared/module_state.pkl", "elsewhere/class_and_ctor_args.pkl"):
        (tmp_path / "run" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "run" / name).write_bytes(pickle.dumps(_RunsCode(str(marker))))
    (tmp_path / "run" / "linked").symlink_to(tmp_path / "run" / "elsewhere", target_is_directory=True)
    original = train_module._restore_checkpoint

    def restore_and_compare(algo, path, state):
        assert any(optimizer["state"]["state"] for optimizer in state["optimizer"].values())  # Adam's moments
        original(algo, path, state)
        now = {key: tensors_only(value) for key, value in algo.get_state(
            components=list(train_module.LEARNER_STATE))["learner_group"]["learner"].items() if key in state}
        _assert_same(now, state)
        restored.append(path)

    monkeypatch.setattr(train_module, "_restore_checkpoint", restore_and_compare)
    train_rllib(factory, TrainConfig(**{**config.__dict__, "total_env_steps": 48}), tmp_path / "run",
                {"command": "test"}, progress=False)
    assert restored == [tmp_path / "run" / "checkpoint.pt"] and not marker.exists()
    latest = json.loads((tmp_path / "run" / "latest.json").read_text())["training"]
    assert latest["env_steps"] == 48 and latest["episodes"] == 4  # resumed at 24 (with new episodes)
    steps = [int(r.split(",")[0]) for r in (tmp_path / "run" / "log.csv").read_text().splitlines()[1:]]
    assert steps == [24, 24, 48, 48]
    with pytest.raises(ValueError, match="other settings"):
        train_rllib(factory, TrainConfig(**{**config.__dict__, "learning_rate": 1.0}), tmp_path / "run", {},
                    progress=False)

    # a crafted checkpoint.pt, or an older release's pickled checkpoint folder, is refused before an env is built
    torch.save({"format": "openmulti.training-checkpoint", "version": 1, "counters": {"env_steps": 48},
                "state": _RunsCode(str(marker))}, tmp_path / "run" / "checkpoint.pt")
    later = TrainConfig(**{**config.__dict__, "total_env_steps": 72})
    with pytest.raises(UnsafeCheckpointError, match="objects other than tensors.*could run code"):
        train_rllib(_no_env, later, tmp_path / "run", {"command": "test"}, progress=False)
    (tmp_path / "run" / "checkpoint").mkdir()
    (tmp_path / "run" / "checkpoint" / "algorithm_state.pkl").write_bytes(pickle.dumps(_RunsCode(str(marker))))
    with pytest.raises(UnsafeCheckpointError, match="RLlib checkpoint folder.*not read.*checkpoint.pt"):
        train_rllib(_no_env, later, tmp_path / "run", {"command": "test"}, progress=False)
    assert not marker.exists()


class _RunsCode:
    """A crafted pickle's payload: unpickling it touches a marker file."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        from pathlib import Path

        return (Path.touch, (Path(self.marker),))


def _no_env(index: int):
    raise AssertionError("no env may be built before the checkpoint is refused")


def _assert_same(a, b) -> None:
    """Nested dicts / lists of tensors and numbers equal, entry by entry."""
    if isinstance(a, dict):
        assert set(a) == set(b)
        for key in a:
            _assert_same(a[key], b[key])
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            _assert_same(x, y)
    elif isinstance(a, torch.Tensor):
        assert torch.equal(a, b)
    else:
        assert a == b


def test_train_refuses_ray_without_the_rllib_backend():
    from openmulti_env.runs.train import train_command

    args = SimpleNamespace(backend="sb3", ray="auto")
    with pytest.raises(ValueError, match="add --backend rllib"):
        train_command(args)


def test_the_round_action_form_is_refused_by_the_rllib_backend(tmp_path):
    pytest.importorskip("ray.rllib")
    from openmulti_env.runs.train import train_command
    from policies.train import TrainConfig
    from policies.train_rllib import train_rllib

    with pytest.raises(ValueError, match="SB3 backend only"):
        train_rllib(lambda index: None, TrainConfig(action_form="round"), tmp_path / "run", {})
    from openmulti_env.runs.cli import build_parser

    args = build_parser().parse_args(["train", "--backend", "rllib", "--action-form", "round"])
    with pytest.raises(ValueError, match="--action-form round trains with the sb3 backend only"):
        train_command(args)
