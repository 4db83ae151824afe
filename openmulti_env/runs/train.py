"""``openmulti train``: the env side of training a communication policy (``policies.train`` does the RL).

``WorldCycle`` is a ParallelEnv that walks a list of worlds (``random:SEED`` rooms by default, never the
scenes the trade-off table reports), switching every few episodes, so that one worker's policy sees many
rooms; each worker starts at its own place in the list. ``train_command`` turns the CLI's options into
an env factory, the training record written beside the policy, and a call of ``policies.train.train``.
"""

from __future__ import annotations

import shlex
import sys
from dataclasses import dataclass, field

import numpy as np
from pettingzoo import ParallelEnv

from openmulti_env.environment.parallel_env import OpenMultiParallelEnv
from openmulti_env.experiment.tree import DEFAULT_PRESETS
from mapping.runtime import cores_each

REPORTED_SCENES = ("room0", "office0", "room2")
"""The trade-off table's scenes: a training list may not hold them."""
DEFAULT_TRAIN_SCENES = tuple(f"random:{k}" for k in range(100, 116))


class WorldCycle(ParallelEnv):
    """The env on ``scenes[(start + k) % len(scenes)]`` for its k-th block of ``episodes_per_world`` episodes
    (the same spaces throughout: one preset, one team size). With recorded episodes every world's env is kept
    (a recorded env holds its probes and recordings, a few MB, and builds in seconds: rebuilt at every change of
    world it cost more than its episodes); a real env is closed when the cycle moves on."""

    metadata = OpenMultiParallelEnv.metadata

    def __init__(self, scenes: tuple[str, ...], start: int = 0, episodes_per_world: int = 2,
                 episode_seeds: int | None = None, **env_kwargs):
        if not scenes:
            raise ValueError("WorldCycle needs at least one scene")
        if episode_seeds is not None and episode_seeds < 1:
            raise ValueError(f"episode_seeds must be at least 1 (or None: a fresh seed every episode), got {episode_seeds}")
        self.episode_seeds = episode_seeds
        self.scenes, self.start, self.episodes_per_world = tuple(scenes), int(start), int(episodes_per_world)
        self.env_kwargs = env_kwargs
        self.episodes = 0
        self.stepped = False  # a reset counts an episode only when steps came before it
        self.summary = {"episode_completion": float("nan"), "episode_mb": float("nan")}
        self.env = OpenMultiParallelEnv(scene=self.scenes[self.start % len(self.scenes)], **env_kwargs)
        self.kept: dict[str, OpenMultiParallelEnv] = {}
        self.possible_agents = list(self.env.possible_agents)
        first = self.possible_agents[0]
        self.spaces = self.env.observation_space(first), self.env.action_space(first)  # kept: the same objects
        self.render_mode = None

    @property
    def agents(self) -> list[str]:
        return self.env.agents

    @property
    def scene(self) -> str:
        """The scene of the current block of episodes."""
        return self.env.config.scene

    def observation_space(self, agent):
        self.env.observation_space(agent)  # names an unknown agent
        return self.spaces[0]

    def action_space(self, agent):
        self.env.action_space(agent)
        return self.spaces[1]

    def reset(self, seed: int | None = None, options: dict | None = None):
        """The next episode; a reset with no step since the last one (RLlib's wrapper resets once when built)
        does not count, so every world gets its ``episodes_per_world`` episodes."""
        self.episodes += self.stepped
        self.stepped = False
        block = self.episodes // self.episodes_per_world
        scene = self.scenes[(self.start + block) % len(self.scenes)]
        if scene != self.env.config.scene:
            if self.env.config.env.episode == "recorded":
                self.kept[self.env.config.scene] = self.env
            else:
                self.env.close()
            self.env = self.kept.pop(scene, None) or OpenMultiParallelEnv(scene=scene, **self.env_kwargs)
        if self.episode_seeds is not None:  # the k-th episode on this world (over every visit), seeds 0..K-1 in turn
            visit = (self.start + block) // len(self.scenes)  # rises by one per visit of this world (offset by start)
            seed = (visit * self.episodes_per_world + self.episodes % self.episodes_per_world) % self.episode_seeds
        observations, infos = self.env.reset(seed=seed, options=options)
        return observations, self._with_summary(infos)

    def step(self, actions):
        self.stepped = True
        observations, rewards, terminations, truncations, infos = self.env.step(actions)
        if not self.env.agents:
            self.summary = {"episode_completion": float(np.mean([i["completion_ratio"] for i in infos.values()])),
                            "episode_mb": float(sum(i["bytes_sent_total"] for i in infos.values()) / 1e6)}
        return observations, rewards, terminations, truncations, self._with_summary(infos)

    def _with_summary(self, infos: dict) -> dict:
        """Every info also carries the last finished episode's team completion (percent) and MB (SuperSuit
        merges the next episode's reset infos into the final step's, so the final values would be lost)."""
        return {agent: {**info, **self.summary} for agent, info in infos.items()}

    @property
    def state_space(self):
        return self.env.state_space

    def state(self):
        return self.env.state()

    def close(self) -> None:
        for env in [self.env, *self.kept.values()]:
            env.close()


@dataclass(frozen=True)
class WorkerEnvs:
    """Picklable factory: world ``index``'s ``WorldCycle`` (it starts ``index`` x its share into the list);
    ``workers`` counts every world of the vector env (workers x worlds per worker)."""

    scenes: tuple[str, ...]
    workers: int
    episodes_per_world: int = 2
    env_kwargs: dict = field(default_factory=dict)
    episode_seeds: int | None = None

    def __call__(self, index: int) -> WorldCycle:
        start = index * max(1, len(self.scenes) // max(self.workers, 1))
        return WorldCycle(self.scenes, start, self.episodes_per_world, self.episode_seeds, **self.env_kwargs)


def check_training_scenes(scenes: tuple[str, ...]) -> None:
    """ValueError when the list holds a scene the trade-off table reports (training on a test scene)."""
    held_out = sorted(set(scenes) & set(REPORTED_SCENES))
    if held_out:
        raise ValueError(f"training scenes {held_out} are the held-out scenes of the trade-off table "
                         f"{REPORTED_SCENES}; train on others (random:SEED rooms by default)")


TRAIN_PRESET = DEFAULT_PRESETS["train"]


def train_config(args) -> "TrainConfig":
    """PPO's settings from the command line (``TrainConfig``'s defaults where none was given)."""
    from openmulti_env.experiment.options import TRAIN_DEST, tree_overrides, typed_overrides  # noqa: PLC0415
    from openmulti_env.experiment.overrides import from_mapping  # noqa: PLC0415
    from policies.train import TrainConfig  # noqa: PLC0415

    return from_mapping(TrainConfig, typed_overrides(tree_overrides(args, TRAIN_DEST), TrainConfig))


def env_settings(args) -> tuple[dict, "Experiment"]:
    """The env's keywords of every training episode (``parallel_env``'s, dotted paths as ``a__b``) and the tree
    they give (for the record): ``--config``'s tree or ``--preset``'s, with the command line's overrides."""
    from openmulti_env.environment.config import env_config  # noqa: PLC0415
    from openmulti_env.experiment import Experiment, read_config  # noqa: PLC0415
    from openmulti_env.experiment.options import tree_overrides, typed_overrides  # noqa: PLC0415

    config = getattr(args, "config", None)
    if config is not None and getattr(args, "preset", None):
        raise ValueError("give --config FILE or --preset NAME, not both (the file's tree names its preset)")
    overrides = typed_overrides(tree_overrides(args), Experiment)
    kwargs = {k.replace(".", "__"): v for k, v in overrides.items()}
    if config is not None:  # --config= is refused by read_config, not ignored
        base = read_config(args.config)
        kwargs = {"preset": base.preset, "config": base, **kwargs}
    else:
        kwargs = {"preset": getattr(args, "preset", None) or TRAIN_PRESET, **kwargs}
    return kwargs, env_config(**kwargs)


def agent_workers_per_env(workers: int) -> int:
    """Agent threads of each training env: the cores shared by the worker processes. An env alone takes one
    per core, and two worker processes with two agent threads each kept four threads on two cores."""
    return cores_each(workers)


NOT_IDENTITY = {"run__workers"}
"""Env keywords that change how fast an episode runs, never what it gives: a run folder resumes across them."""

SUMMARISED = {"world__num_agents", "env__reward", "env__comm_cost_per_mb", "channel__budget_mb", "env__horizon",
              "env__reward_baseline", "env__comm_cost_of_always"}


def env_summary(tree, env_kwargs: dict) -> dict:
    """The env's settings as a training record has said them since the first runs (a run folder resumes only
    under the same), and any other override given."""
    summary = {"preset": tree.preset, "num_agents": tree.num_agents, "reward": tree.env.reward,
               "comm_cost_per_mb": tree.env.comm_cost_per_mb, "comm_budget_mb": tree.channel.budget_mb,
               **({"horizon": tree.env.horizon} if tree.env.horizon else {}),
               **({"reward_baseline": tree.env.reward_baseline, "comm_cost_of_always": tree.env.comm_cost_of_always}
                  if tree.env.reward_baseline != "none" else {})}
    others = {k: v for k, v in env_kwargs.items() if k not in SUMMARISED | NOT_IDENTITY | {"preset", "config"}}
    return {**summary, **({"overrides": others} if others else {})}


def training_title(tree, config) -> str:
    """The learning curve's title: preset, team, reward and cost, action form and critic."""
    reward = {"none": f"cost {tree.env.comm_cost_per_mb}/MB",
              "front": "reward: the margin over the fixed-rate front"}.get(
        tree.env.reward_baseline, f"reward over never/always, cost {tree.env.comm_cost_of_always} x always's bytes")
    form = "" if config.action_form == "entries" else f", {config.action_form} form"
    if config.payload != "everything":
        form += f" sending {config.payload}'s choice"
    critic = ", central critic" if config.critic == "central" else ""
    return f"{tree.preset}, {tree.num_agents} agents, {reward}{form}{critic}"


def train_command(args) -> int:
    """``openmulti train``: build the env factory and the record, train, say where the policy is."""
    from policies.gate import payload_rule  # noqa: PLC0415
    from policies.train import train  # noqa: PLC0415
    from openmulti_env.environment.config import env_config  # noqa: PLC0415
    from openmulti_env.experiment import tree_record  # noqa: PLC0415

    backend = getattr(args, "backend", "sb3")
    if getattr(args, "ray", None) and backend != "rllib":
        raise ValueError("--ray trains on a Ray cluster with RLlib: add --backend rllib")
    needs = {"sb3": (("stable_baselines3", "supersuit"), "openmulti[train]"), "rllib": (("ray.rllib",), "openmulti[ray]")}
    modules, extra = needs[backend]
    for module in modules:
        try:
            __import__(module)
        except ImportError:
            raise ValueError(f"openmulti train --backend {backend} needs {module}: pip install '{extra}' (make setup "
                             "installs it)") from None

    config = train_config(args)
    if config.action_form != "entries" and backend == "rllib":
        raise ValueError(f"--action-form {config.action_form} trains with the sb3 backend only (RLlib's module draws one "
                         "Bernoulli per action entry)")
    if backend == "rllib" and (config.critic != "local" or config.read_links):
        raise ValueError("--critic central and --read-links train with the sb3 backend only (RLlib's module here is the "
                         "shared actor-critic over map and comm)")
    scenes = tuple(args.scenes) if args.scenes else DEFAULT_TRAIN_SCENES
    check_training_scenes(scenes)
    env_kwargs, tree = env_settings(args)
    if payload_rule(config.payload) is not None:  # the rule picks instances: the env acts in the instances form
        if config.action_form != "team" or backend != "sb3":
            raise ValueError(f"--payload {config.payload} gates the team form: add --action-form team (sb3 backend)")
        if env_kwargs.get("env__action_form", "instances") != "instances":
            raise ValueError(f"--payload {config.payload} acts on the instances action form, not "
                             f"{env_kwargs['env__action_form']!r}")
        env_kwargs["env__action_form"] = "instances"
        tree = env_config(**env_kwargs)
    if tree.env.reward_baseline != "none" and not getattr(args, "episode_seeds", None):
        print(f"[openmulti] warning: --reward-baseline {tree.env.reward_baseline} without --episode-seeds K plays more "
              "episodes (never, always and, for the front, its fixed schedules) for every training episode, each on a "
              "fresh seed that is never reused; --episode-seeds 2 plays them once per world and seed", file=sys.stderr)
    if tree.run.workers is None:  # the worker processes split the cores: each env's agents take turns on its own
        # (a Ray cluster's env runners get one CPU each, whatever this machine has)
        env_kwargs["run__workers"] = 1 if getattr(args, "ray", None) else agent_workers_per_env(config.workers)
    factory = WorkerEnvs(scenes, config.workers * config.worlds_per_worker, args.episodes_per_world, env_kwargs,
                         getattr(args, "episode_seeds", None))
    record = {"command": "openmulti train " + " ".join(shlex.quote(a) for a in sys.argv[2:]), "scenes": list(scenes),
              "env": env_summary(tree, env_kwargs), "experiment": tree_record(tree),
              "title": training_title(tree, config),
              **({"episode_seeds": args.episode_seeds} if getattr(args, "episode_seeds", None) else {})}
    if backend == "rllib":
        from policies.train_rllib import train_rllib  # noqa: PLC0415

        best = train_rllib(factory, config, args.out, record, address=args.ray, progress=True)
    else:
        best = train(factory, config, args.out, record, progress=True)
    print(f"[openmulti] best policy: {best} (run it: openmulti run --policy {best}); learning curve: "
          f"{args.out}/learning_curve.png, log: {args.out}/log.csv")
    return 0
