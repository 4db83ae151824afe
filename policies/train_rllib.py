"""Train the shared communication policy with RLlib's multi-agent PPO, on this machine or a Ray cluster.

The same run as ``policies.train`` (SB3), in RLlib's terms: one module ``shared`` that every agent maps to
(parameter sharing: the agents are identical robots), ``workers`` env runners each stepping its own env,
PPO updates on the learner in this process. Same settings (``TrainConfig``; RLlib's PPO loss set to SB3's:
no KL term, value weight 0.5, gradient norm 0.5), same run folder (resumable checkpoint, ``log.csv``,
``learning_curve.png``, ``latest`` / ``best`` policy files the CLI loads). The two are not the same
algorithm to the digit (advantage normalisation, minibatching and seeding differ). Why a second backend: RLlib scales the env runners over a cluster
(``address``), which an env at about one step per second needs.

Read top to bottom: settings -> the last checkpoint, if any -> Ray -> the env registered for the runners -> PPO
config with ``CommRLModule`` -> the algorithm, with the checkpoint's state put into it -> train iterations, each
logging its finished episodes, checkpointing every ``chunk_env_steps`` and exporting the policy. A checkpoint
is ``checkpoint.pt``: the learner's module and optimiser state as tensors and the step counters
(``policies.safe_checkpoint``), never RLlib's own pickled checkpoint folder, so resuming runs no code from the
run folder. ``env_factory(index)`` makes runner
``index``'s ParallelEnv; this module imports no env (of the env, only its
observation layout).
"""

from __future__ import annotations

import os
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np

from policies.safe_checkpoint import (UnsafeCheckpointError, load_training_state, refuse_pickled_rllib_checkpoint,
                                      save_training_state, tensors_only)
from policies.train import EpisodeLog, TrainConfig, claim_run_folder

ENV_NAME = "openmulti_comm"
MODULE = "shared"
EPISODES_KEY = "openmulti_episodes"
"""The env runners' metric holding one (runner, return, completion, MB) item per finished episode."""


def _episode_rows_callback():
    """An RLlib callback class logging each finished episode's mean agent return and the team's final
    completion and MB (from the infos' ``episode_completion`` / ``episode_mb``; NaN when absent)."""
    from ray.rllib.callbacks.callbacks import RLlibCallback  # noqa: PLC0415

    class EpisodeRows(RLlibCallback):
        def on_episode_end(self, *, episode, prev_episode_chunks=None, env_runner=None, metrics_logger=None,
                           **kwargs) -> None:
            infos = episode.get_infos(-1)
            first = next(iter(infos.values()), {})
            agents = max(len(episode.agent_ids), 1)
            # an episode cut at a sample boundary arrives as its last chunk: its return needs the earlier ones
            total = float(episode.get_return()) + sum(float(c.get_return()) for c in prev_episode_chunks or ())
            metrics_logger.log_value(EPISODES_KEY, (int(getattr(env_runner, "worker_index", 0) or 0),
                                                    total / agents,
                                                    float(first.get("episode_completion", np.nan)),
                                                    float(first.get("episode_mb", np.nan))), reduce="item_series")

    return EpisodeRows


def _env_creator(env_factory: Callable[[int], object], worlds_per_runner: int = 1):
    """RLlib's env creator: the j-th env runner k makes (1-based; 0 is the local runner) gets
    ``env_factory((k - 1) * worlds_per_runner + j)``. RLlib's multi-agent runner gives all its envs one context
    (``vector_index`` 0), so j counts the envs this process has made (each runner unpickles its own counter)."""
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv  # noqa: PLC0415

    made = [0]

    def create(context) -> ParallelPettingZooEnv:
        runner = max(int(getattr(context, "worker_index", 0)) - 1, 0)
        index = runner * worlds_per_runner + made[0] % worlds_per_runner
        made[0] += 1
        return ParallelPettingZooEnv(env_factory(index))

    return create


LEARNER_STATE = ("learner_group/learner/rl_module", "learner_group/learner/optimizer")
"""What a checkpoint keeps of the algorithm: the learner's module weights and optimiser state. The env runners
get the weights from the learner; their connectors hold no state (no observation filter is configured)."""


def _save_checkpoint(algo, path: Path, env_steps: int) -> None:
    """The learner's module and optimiser state (tensors) and the run's counters into ``path``, atomically."""
    from ray.rllib.core import COMPONENT_LEARNER, COMPONENT_LEARNER_GROUP  # noqa: PLC0415

    learner = algo.get_state(components=list(LEARNER_STATE))[COMPONENT_LEARNER_GROUP][COMPONENT_LEARNER]
    state = {key: tensors_only(learner[key], key) for key in ("rl_module", "optimizer")}
    save_training_state(path, state, {"env_steps": int(env_steps), "iterations": int(algo.iteration)})


def _restore_checkpoint(algo, path: Path, state: dict) -> None:
    """Put a checkpoint's learner state into the freshly built ``algo`` (weights synced to the env runners);
    UnsafeCheckpointError when it does not fit this run's module."""
    from ray.rllib.core import COMPONENT_LEARNER, COMPONENT_LEARNER_GROUP  # noqa: PLC0415

    if set(state) != {"rl_module", "optimizer"} or set(state["rl_module"]) != {MODULE}:
        raise UnsafeCheckpointError(f"{path} holds {sorted(state)}, not this run's learner state; delete it (or "
                                    "train into a new --out) to start again")
    try:
        algo.set_state({COMPONENT_LEARNER_GROUP: {COMPONENT_LEARNER: state}})
    except (KeyError, ValueError, RuntimeError, TypeError) as exc:
        raise UnsafeCheckpointError(f"{path} does not fit this run's policy ({str(exc)[:200]}); delete it (or train "
                                    "into a new --out) to start again") from None


def train_rllib(env_factory: Callable[[int], object], config: TrainConfig, out: str | Path, training_record: dict,
                address: str | None = None, progress: bool = True) -> Path:
    """Train (or resume) in ``out`` with RLlib PPO; returns the path of the best policy file.

    Args:
        address: None or ``local``: a Ray started on this machine (or the one this process already joined);
            else a cluster's address (``ray://host:10001``, ``host:6379``, ``auto``).
    """
    try:
        import ray  # noqa: PLC0415
        from ray.rllib.algorithms.ppo import PPOConfig  # noqa: PLC0415
        from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec  # noqa: PLC0415
        from ray.rllib.core.rl_module.rl_module import RLModuleSpec  # noqa: PLC0415
        from ray.rllib.utils.metrics import ENV_RUNNER_RESULTS, NUM_ENV_STEPS_SAMPLED_LIFETIME  # noqa: PLC0415
        from ray.tune.registry import register_env  # noqa: PLC0415
    except ImportError:
        raise ImportError("--backend rllib needs RLlib: pip install 'openmulti[ray]'") from None
    from tqdm import tqdm  # noqa: PLC0415

    from policies.files import save_policy  # noqa: PLC0415
    from policies.network import NetworkConfig  # noqa: PLC0415
    from openmulti_env.environment.layout import MAP_CHANNELS  # noqa: PLC0415
    from policies.rllib_module import CommRLModule, export_module  # noqa: PLC0415

    if config.action_form != "entries":
        raise ValueError(f"action form {config.action_form!r} trains with the SB3 backend only (policies.train); "
                         "RLlib's module draws one Bernoulli per action entry")
    if config.workers < 1:
        raise ValueError(f"the RLlib backend needs at least one env runner (--workers), got {config.workers}")
    if config.worlds_per_worker < 1:
        raise ValueError(f"--worlds-per-worker must be at least 1, got {config.worlds_per_worker}")
    out = Path(out)
    settings = claim_run_folder(out, {"train": asdict(config), "backend": "rllib", **training_record})

    # ---- the last checkpoint, read before an env or Ray starts (tensors only: resuming runs no code) ----
    checkpoint = out / "checkpoint.pt"
    refuse_pickled_rllib_checkpoint(out / "checkpoint")
    state, counters = load_training_state(checkpoint) if checkpoint.exists() else (None, {})
    resumed_at = int(counters.get("env_steps", 0))

    # ---- the policy's shapes, from one env --------------------------------------------------------------
    probe = env_factory(0)
    agent = probe.possible_agents[0]
    num_agents = len(probe.possible_agents)
    network_config = NetworkConfig(map_channels=len(MAP_CHANNELS),
                                   comm_size=int(probe.observation_space(agent)["comm"].shape[0]),
                                   actions=int(probe.action_space(agent).n)).as_dict()
    probe.close()

    log = EpisodeLog(out / "log.csv", num_agents)

    # ---- Ray: here or on a cluster ------------------------------------------------------------------------
    started_here = not ray.is_initialized()
    if started_here:
        local = address in (None, "local")
        ray.init(address=None if local else address, include_dashboard=False, log_to_driver=False,
                 configure_logging=False, **({"num_cpus": max(os.cpu_count() or 1, config.workers)} if local else {}))
    try:
        cpus = ray.cluster_resources().get("CPU", 0.0)
        if cpus < config.workers:  # the env runners would wait for CPUs forever, and say nothing
            raise ValueError(f"{config.workers} env runners (--workers) ask for 1 CPU each but the Ray cluster has "
                             f"{cpus:g}")
        register_env(ENV_NAME, _env_creator(env_factory, config.worlds_per_worker))
        # ---- PPO: every agent maps to one shared module ----------------------------------------------------
        ppo = (PPOConfig()
               .environment(ENV_NAME, disable_env_checking=True)
               .framework("torch")
               .env_runners(num_env_runners=config.workers, num_envs_per_env_runner=config.worlds_per_worker,
                            rollout_fragment_length=config.n_steps, sample_timeout_s=3600.0,
                            num_cpus_per_env_runner=1)
               .learners(num_learners=0)
               .multi_agent(policies={MODULE}, policy_mapping_fn=lambda agent_id, episode, **kw: MODULE)
               .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs={
                   MODULE: RLModuleSpec(module_class=CommRLModule, model_config=network_config)}))
               .training(train_batch_size_per_learner=config.n_steps * config.workers * config.worlds_per_worker,
                         minibatch_size=config.batch_size, num_epochs=config.n_epochs, lr=config.learning_rate,
                         gamma=config.gamma, lambda_=config.gae_lambda, entropy_coeff=config.ent_coef,
                         clip_param=config.clip_range,
                         # SB3's PPO loss where RLlib's defaults differ: no KL term, value loss weight 0.5, no
                         # value clipping, gradients clipped to global norm 0.5
                         use_kl_loss=False, vf_loss_coeff=0.5, vf_clip_param=float("inf"), grad_clip=0.5,
                         grad_clip_by="global_norm")
               .callbacks(_episode_rows_callback())
               .debugging(seed=config.seed + resumed_at))  # a resumed run draws new episodes, not the first ones
        algo = ppo.build_algo()

        # ---- fresh, or from the last checkpoint ------------------------------------------------------------
        # (a rebuilt algorithm counts env steps from 0: the run's count is the checkpoint's plus RLlib's)
        env_steps = resumed_at
        if state is not None:
            _restore_checkpoint(algo, checkpoint, state)
            print(f"[openmulti] resumed RLlib training at {env_steps} env steps from {checkpoint}")

        # ---- train iterations: log, checkpoint and export every chunk ---------------------------------------
        best = log.rolling_return(config.rolling) if (out / "best.json").exists() else -np.inf
        next_chunk = (env_steps // config.chunk_env_steps + 1) * config.chunk_env_steps
        with tqdm(total=config.total_env_steps, initial=min(env_steps, config.total_env_steps), desc="training (rllib)",
                  unit="env step", disable=not progress) as bar:
            while env_steps < config.total_env_steps:
                result = algo.train()
                runners = result.get(ENV_RUNNER_RESULTS, {})
                now = resumed_at + int(runners.get(NUM_ENV_STEPS_SAMPLED_LIFETIME, env_steps - resumed_at))
                for runner, episode_return, completion, mb in runners.get(EPISODES_KEY, []) or []:
                    log.add(now, max(runner - 1, 0), episode_return, completion, mb)
                bar.update(min(now, config.total_env_steps) - min(env_steps, config.total_env_steps))
                env_steps = now
                bar.set_postfix(episodes=len(log.rows), rolling_return=f"{log.rolling_return(config.rolling):.3f}")
                if env_steps < next_chunk and env_steps < config.total_env_steps:
                    continue
                next_chunk = (env_steps // config.chunk_env_steps + 1) * config.chunk_env_steps
                _save_checkpoint(algo, checkpoint, env_steps)
                network = export_module(algo.get_module(MODULE))
                record = {**settings, "env_steps": env_steps, "episodes": len(log.rows),
                          "rolling_return": log.rolling_return(config.rolling)}
                save_policy(out / "latest", network, num_agents, record)
                if log.rows and log.rolling_return(config.rolling) > best or not (out / "best.json").exists():
                    best = log.rolling_return(config.rolling) if log.rows else best
                    save_policy(out / "best", network, num_agents, record)
                log.write()
                log.plot(out / "learning_curve.png", f"{training_record.get('title', 'training')} (RLlib): "
                                                     f"{len(log.rows)} episodes, {env_steps} env steps")
        algo.stop()
    finally:
        if started_here:
            ray.shutdown()
    return out / "best.json"

