"""Train a shared communication policy with PPO (Stable-Baselines3) on any env with this contract.

Why SB3 + SuperSuit: it trains on the env today with parameter sharing (every agent one entry of a vector
env, one policy: the agents are identical robots) and process workers; TorchRL 0.14 wraps the env but
BenchMARL, its MARL trainer, requires torchrl < 0.12; RLlib pins gymnasium 1.2.2 (the cluster backend of
the Ray issue). SuperSuit is semi-deprecated upstream; its two calls are isolated in ``policies.sb3_vec``.

Read top to bottom: settings -> vector env over worker processes -> PPO with ``CommFeatures`` as its
features extractor -> learn in chunks, each followed by a checkpoint (resumable), the policy file of the
latest and of the best rolling return, the CSV log and its PNG. ``env_factory(index)`` makes the env of
worker ``index`` (the CLI passes one that walks a distribution of worlds); this module imports no env (of
the env, only its observation layout).
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class TrainConfig:
    """PPO's settings and the run's size."""

    total_env_steps: int = 20_000
    """Env steps (rounds of one team) over all workers; agent transitions are this times the team size."""
    workers: int = 2
    """Worker processes (1: this process); at most one per core."""
    worlds_per_worker: int = 1
    """Envs (worlds) each worker steps in turn: they share its process's text encoder, world and frame caches,
    so K worlds cost less memory than K workers (``docs/profile.md``: memory per env)."""
    n_steps: int = 32
    """Rounds per worker and agent between two updates."""
    batch_size: int = 64
    n_epochs: int = 4
    learning_rate: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    ent_coef: float = 0.01
    clip_range: float = 0.2
    seed: int = 0
    chunk_env_steps: int = 512
    """A checkpoint, a policy file and a log flush every this many env steps."""
    rolling: int = 20
    """Episodes in the rolling mean that picks the best policy."""
    action_form: str = "entries"
    """``entries``: a Bernoulli per action entry; ``round``: one per agent, send everything or nothing; ``team``:
    one for the whole team from every agent's observation (``policies.gate``)."""
    payload: str = "everything"
    """What the ``team`` form's 1 sends: ``everything`` (every entry of every agent) or ``instance_novelty`` (what that
    rule picks for each agent this round; settings after a colon): the policy learns when, the rule says what."""
    critic: str = "local"
    """``local``: the value function reads the actor's observation; ``central``: ``state()`` and the agent's
    ``comm`` (MAPPO; ``policies.critic``)."""
    read_links: bool = False
    """The policy reads the ``links`` observation (which links were up, what they carry) beside ``comm``: needed
    to time messages when links come and go (``link_range_m``, ``link_mb_per_round``)."""
    tensorboard: bool = True
    """TensorBoard logs under ``OUT/tensorboard`` (episodes at env steps; PPO's losses under ``ppo``); sb3 backend."""


ADDED_AFTER_RUNS = ("critic", "read_links", "action_form", "payload", "worlds_per_worker")
"""``TrainConfig`` fields added after training runs were made, each defaulting to the behaviour from before it
(the local critic, no links read, the entries form, everything sent, one world a worker): a run folder without
them resumes as if it had their defaults."""


def same_run(old: dict, new: dict) -> bool:
    """Whether two runs' settings differ only in how long they train (and the command line that said so)."""
    def core(settings: dict) -> dict:
        kept = {k: v for k, v in settings.items() if k not in ("command", "title", "experiment")}
        kept["train"] = {k: v for k, v in settings.get("train", {}).items() if k not in ("total_env_steps", "tensorboard")}
        for name in ADDED_AFTER_RUNS:  # a run begun before the setting existed had its default's behaviour
            kept["train"].setdefault(name, getattr(TrainConfig, name))
        return kept
    return core(old) == core(new)


def claim_run_folder(out: Path, settings: dict) -> dict:
    """Make ``out`` the folder of a run with ``settings`` (written to ``settings.json``); ValueError when it
    holds a run with other settings (a resume must keep them, only its length may grow)."""
    out.mkdir(parents=True, exist_ok=True)
    settings_path = out / "settings.json"
    if settings_path.exists() and not same_run(json.loads(settings_path.read_text()), settings):
        raise ValueError(f"{out} holds a training run with other settings ({settings_path}); resume it with the same "
                         "settings (--env-steps may grow) or use another --out")
    settings_path.write_text(json.dumps(settings, indent=2) + "\n")
    return settings


def features_extractor_class(form: str = "entries"):
    """SB3's extractor around ``CommFeatures`` (SB3 imported only when training); in the ``team`` form it reads
    the team's stacked observations, (B, N, ...), and pools the agents' features (``network.team_pool``)."""
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor  # noqa: PLC0415

    from policies.network import CommFeatures, NetworkConfig, team_pool  # noqa: PLC0415

    class SB3CommFeatures(BaseFeaturesExtractor):
        def __init__(self, observation_space, config: dict):
            net_config = NetworkConfig.from_dict(config)
            super().__init__(observation_space, net_config.head_inputs)
            self.net = CommFeatures(net_config)

        def forward(self, observations):
            return self.net(observations)

    class SB3TeamFeatures(SB3CommFeatures):
        def forward(self, observations):
            maps = observations["map"]  # (B, N, H, W, C) floats in [0, 255]: not an image to SB3 (4 axes)
            batch, agents = maps.shape[:2]
            planes = maps.flatten(0, 1).permute(0, 3, 1, 2) / 255.0
            parts = dict(map=planes, comm=observations["comm"].flatten(0, 1))
            if "links" in observations:
                parts["links"] = observations["links"].flatten(0, 1)
            features = self.net(parts)
            return team_pool(features.view(batch, agents, -1))

    return SB3TeamFeatures if form == "team" else SB3CommFeatures


class EpisodeLog:
    """Per finished episode (one row per worker env): env steps so far, return, and the final completion and
    MB from the infos' ``episode_completion`` / ``episode_mb`` (NaN when the env does not give them)."""

    FIELDS = ("env_steps", "worker", "return", "completion", "mb")

    def __init__(self, path: Path, num_agents: int):
        self.path, self.n = path, num_agents
        self.rows = list(csv.DictReader(path.open())) if path.exists() else []
        self.rows = [{k: int(float(v)) if k in ("env_steps", "worker") else float(v) for k, v in r.items()}
                     for r in self.rows]
        self.returns: np.ndarray | None = None

    def add(self, env_steps: int, worker: int, episode_return: float, completion: float, mb: float) -> None:
        """One finished episode (the form a trainer that sees whole episodes, e.g. RLlib's, logs)."""
        self.rows.append({"env_steps": int(env_steps), "worker": int(worker), "return": float(episode_return),
                          "completion": float(completion), "mb": float(mb)})

    def step(self, rewards: np.ndarray, dones: np.ndarray, infos: list[dict], env_steps: int) -> None:
        """One step of SB3's vector env (every agent of every worker an entry)."""
        if self.returns is None:
            self.returns = np.zeros(len(rewards))
        self.returns += rewards
        for w in range(len(rewards) // self.n):
            agents = slice(w * self.n, (w + 1) * self.n)
            if np.all(dones[agents]):
                first = infos[agents][0]
                self.add(env_steps, w, self.returns[agents].mean(), first.get("episode_completion", np.nan),
                         first.get("episode_mb", np.nan))
                self.returns[agents] = 0.0

    def rolling_return(self, window: int) -> float:
        return float(np.mean([r["return"] for r in self.rows[-window:]])) if self.rows else -np.inf

    def write(self) -> None:
        tmp = self.path.with_suffix(".tmp")
        with tmp.open("w", newline="") as f:
            writer = csv.DictWriter(f, self.FIELDS)
            writer.writeheader()
            writer.writerows(self.rows)
        os.replace(tmp, self.path)

    def plot(self, png: Path, title: str) -> None:
        import matplotlib  # noqa: PLC0415

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # noqa: PLC0415

        if not self.rows:
            return
        steps = np.array([r["env_steps"] for r in self.rows])
        fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
        for ax, key, label in zip(axes, ("return", "completion", "mb"),
                                  ("episode return", "final completion ratio (%)", "MB sent by the team")):
            values = np.array([r[key] for r in self.rows])
            ax.plot(steps, values, ".", alpha=0.35, color="tab:blue")
            k = min(len(values), 10)
            xs, group = np.unique(steps, return_inverse=True)
            if len(xs) < len(steps):  # rows share their env steps (RLlib logs at the end of each iteration)
                ax.plot(xs, [np.nanmean(values[group == g]) for g in range(len(xs))], color="tab:red",
                        label="mean per iteration")
                ax.legend(loc="best", fontsize=8)
            elif k > 1:
                ax.plot(steps[k - 1:], np.convolve(values, np.ones(k) / k, mode="valid"), color="tab:red",
                        label=f"mean of {k}")
                ax.legend(loc="best", fontsize=8)
            ax.set_xlabel("env steps")
            ax.set_title(label, fontsize=10)
            ax.grid(alpha=0.3)
        fig.suptitle(title, fontsize=10)
        fig.tight_layout()
        fig.savefig(png.with_suffix(".tmp.png"), dpi=110)
        plt.close(fig)
        os.replace(png.with_suffix(".tmp.png"), png)


def export_network(model, network_config: dict):
    """The trained SB3 policy as a ``CommPolicyNetwork`` (features extractor + action head)."""
    from policies.network import CommPolicyNetwork, NetworkConfig  # noqa: PLC0415

    network = CommPolicyNetwork(NetworkConfig.from_dict(network_config))
    network.features.load_state_dict(model.policy.pi_features_extractor.net.state_dict())
    network.action.load_state_dict(model.policy.action_net.state_dict())
    return network.eval()


def train(env_factory: Callable[[int], object], config: TrainConfig, out: str | Path, training_record: dict,
          progress: bool = True) -> Path:
    """Train (or resume) in ``out``; returns the path of the best policy file (``out/best.json``)."""
    import torch  # noqa: PLC0415
    from stable_baselines3 import PPO  # noqa: PLC0415
    from stable_baselines3.common.callbacks import BaseCallback  # noqa: PLC0415
    from stable_baselines3.common.utils import set_random_seed  # noqa: PLC0415

    from policies.files import save_policy  # noqa: PLC0415
    from policies.critic import StateFactory, central_critic_policy, check_critic  # noqa: PLC0415
    from policies.gate import GatedFactory, TeamFactory, check_action_form, payload_rule  # noqa: PLC0415
    from policies.network import NetworkConfig  # noqa: PLC0415
    from openmulti_env.environment.layout import MAP_CHANNELS  # noqa: PLC0415
    from policies.safe_checkpoint import (UnsafeCheckpointError, load_training_state,  # noqa: PLC0415
                                          refuse_pickled_checkpoint, save_training_state)
    from policies.sb3_vec import sb3_vec_env_from_factory  # noqa: PLC0415

    form, critic = check_action_form(config.action_form), check_critic(config.critic)  # before the folder is claimed
    if payload_rule(config.payload) is not None and form != "team":
        raise ValueError(f"--payload {config.payload} gates the team form: add --action-form team")
    out = Path(out)
    settings = claim_run_folder(out, {"train": asdict(config), **training_record})

    # ---- the vector env: every agent of every worker's env one entry, one shared policy -------------------
    # (the round form learns on a gated env: one action entry per agent, broadcast to the env's entries; the team
    # form on an env whose one agent is the team, sending everything or the payload rule's choice; a central
    # critic adds state() to every observation)
    factory = StateFactory(env_factory) if critic == "central" else env_factory
    factory = {"round": GatedFactory, "team": lambda f: TeamFactory(f, config.payload)}.get(form, lambda f: f)(factory)
    vec, entries_per_world = sb3_vec_env_from_factory(factory, config.workers, config.seed, config.worlds_per_worker)
    space = vec.observation_space
    comm_shape = space["comm"].shape
    num_agents = comm_shape[0] if form == "team" else entries_per_world  # the team's size
    entries = 2 * (num_agents - 1) if form != "entries" else int(vec.action_space.n)  # the env's layout (policies.scripted)
    links = space.spaces.get("links")
    link_inputs = int(np.prod(links.shape[-2:])) if links is not None and config.read_links else 0
    network_config = NetworkConfig(map_channels=len(MAP_CHANNELS), comm_size=int(comm_shape[-1]),
                                   actions=entries, action_form=form, link_inputs=link_inputs,
                                   payload=config.payload).as_dict()

    # ---- PPO, fresh or from the last checkpoint ----------------------------------------------------------
    # (tensors only: a checkpoint is read with weights_only=True, so resuming never runs code)
    checkpoint = out / "checkpoint.pt"
    refuse_pickled_checkpoint(out / "checkpoint.zip")
    log = EpisodeLog(out / "log.csv", entries_per_world)
    set_random_seed(config.seed)  # the networks' initialisation (the envs are seeded through reset)
    model = PPO(central_critic_policy() if critic == "central" else "MultiInputPolicy", vec, n_steps=config.n_steps, batch_size=config.batch_size,
                n_epochs=config.n_epochs, learning_rate=config.learning_rate, gamma=config.gamma,
                gae_lambda=config.gae_lambda, ent_coef=config.ent_coef, clip_range=config.clip_range,
                device="cpu", verbose=0,
                policy_kwargs=dict(features_extractor_class=features_extractor_class(form),
                                   features_extractor_kwargs=dict(config=network_config),
                                   net_arch=dict(pi=[], vf=[64])))
    if checkpoint.exists():
        state, counters = load_training_state(checkpoint)
        try:
            model.set_parameters(state, exact_match=True, device="cpu")
            model.num_timesteps, model._n_updates = counters["num_timesteps"], counters["n_updates"]
        except (KeyError, ValueError, RuntimeError, TypeError) as exc:
            raise UnsafeCheckpointError(f"{checkpoint} does not fit this run's policy ({exc}); delete it (or train "
                                        "into a new --out) to start again") from None
        print(f"[openmulti] resumed training at {model.num_timesteps // entries_per_world} env steps from {checkpoint}")

    from policies.board import TrainingBoard  # noqa: PLC0415

    board = TrainingBoard(out / "tensorboard", model, len(log.rows)) if config.tensorboard else None
    learner_threads = torch.get_num_threads()

    class Logging(BaseCallback):
        """Logs each step's episodes; the learner's torch threads follow the phase: one while collecting (a batch
        of a few observations a step, the env workers busy on the cores: a second thread waiting on a busy core made
        each forward pass 30x slower here), the cores while updating (the workers idle)."""

        def _on_rollout_start(self) -> None:
            torch.set_num_threads(1)

        def _on_rollout_end(self) -> None:
            torch.set_num_threads(learner_threads)

        def _on_step(self) -> bool:
            log.step(np.asarray(self.locals["rewards"], float), np.asarray(self.locals["dones"]),
                     list(self.locals["infos"]), self.num_timesteps // entries_per_world)
            return True

    # ---- learn in chunks: checkpoint, policy files, log after each -----------------------------------------
    best = log.rolling_return(config.rolling) if (out / "best.json").exists() else -np.inf
    from tqdm import tqdm  # noqa: PLC0415

    try:
        with tqdm(total=config.total_env_steps, initial=min(model.num_timesteps // entries_per_world, config.total_env_steps),
                  desc="training", unit="env step", disable=not progress) as bar:
            while model.num_timesteps // entries_per_world < config.total_env_steps:
                before = model.num_timesteps
                # the last chunk is what is left (SB3 still collects whole rollouts)
                left = config.total_env_steps - model.num_timesteps // entries_per_world
                model.learn(total_timesteps=min(config.chunk_env_steps, left) * entries_per_world, reset_num_timesteps=False,
                            callback=Logging())
                save_training_state(checkpoint, model.get_parameters(),
                                    {"num_timesteps": int(model.num_timesteps), "n_updates": int(model._n_updates)})
                env_steps = model.num_timesteps // entries_per_world
                record = {**settings, "env_steps": env_steps, "episodes": len(log.rows),
                          "rolling_return": log.rolling_return(config.rolling)}
                save_policy(out / "latest", export_network(model, network_config), num_agents, record)
                if log.rows and log.rolling_return(config.rolling) > best:
                    best = log.rolling_return(config.rolling)
                    save_policy(out / "best", export_network(model, network_config), num_agents, record)
                log.write()
                if board is not None:  # with the CSV, so a resumed run writes no episode twice
                    board.episodes(log.rows)
                log.plot(out / "learning_curve.png", f"{training_record.get('title', 'training')}: {len(log.rows)} "
                                                     f"episodes, {env_steps} env steps")
                bar.update((model.num_timesteps - before) // entries_per_world)
                bar.set_postfix(episodes=len(log.rows), rolling_return=f"{log.rolling_return(config.rolling):.3f}")
    finally:
        vec.close()
        if board is not None:
            board.close()
    if not (out / "best.json").exists():
        save_policy(out / "best", export_network(model, network_config), num_agents,
                    {**settings, "env_steps": model.num_timesteps // entries_per_world, "episodes": len(log.rows)})
    return out / "best.json"
