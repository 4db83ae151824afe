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

REPORTED_SCENES = ("room0", "office0", "room2")
"""The trade-off table's scenes: a training list may not hold them."""
DEFAULT_TRAIN_SCENES = tuple(f"random:{k}" for k in range(100, 116))


class WorldCycle(ParallelEnv):
    """The env on ``scenes[(start + k) % len(scenes)]`` for its k-th block of ``episodes_per_world`` episodes
    (the same spaces throughout: one preset, one team size)."""

    metadata = OpenMultiParallelEnv.metadata

    def __init__(self, scenes: tuple[str, ...], start: int = 0, episodes_per_world: int = 2, **env_kwargs):
        if not scenes:
            raise ValueError("WorldCycle needs at least one scene")
        self.scenes, self.start, self.episodes_per_world = tuple(scenes), int(start), int(episodes_per_world)
        self.env_kwargs = env_kwargs
        self.episodes = 0
        self.stepped = False  # a reset counts an episode only when steps came before it
        self.summary = {"episode_completion": float("nan"), "episode_mb": float("nan")}
        self.env = OpenMultiParallelEnv(scene=self.scenes[self.start % len(self.scenes)], **env_kwargs)
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
            self.env.close()
            self.env = OpenMultiParallelEnv(scene=scene, **self.env_kwargs)
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

    def state(self):
        return self.env.state()

    def close(self) -> None:
        self.env.close()


@dataclass(frozen=True)
class WorkerEnvs:
    """Picklable factory: worker ``index``'s ``WorldCycle`` (it starts ``index`` x its share into the list)."""

    scenes: tuple[str, ...]
    workers: int
    episodes_per_world: int = 2
    env_kwargs: dict = field(default_factory=dict)

    def __call__(self, index: int) -> WorldCycle:
        start = index * max(1, len(self.scenes) // max(self.workers, 1))
        return WorldCycle(self.scenes, start, self.episodes_per_world, **self.env_kwargs)


def check_training_scenes(scenes: tuple[str, ...]) -> None:
    """ValueError when the list holds a scene the trade-off table reports (training on a test scene)."""
    held_out = sorted(set(scenes) & set(REPORTED_SCENES))
    if held_out:
        raise ValueError(f"training scenes {held_out} are the held-out scenes of the trade-off table "
                         f"{REPORTED_SCENES}; train on others (random:SEED rooms by default)")


def train_command(args) -> int:
    """``openmulti train``: build the env factory and the record, train, say where the policy is."""
    from policies.train import TrainConfig, train  # noqa: PLC0415

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

    action_form = getattr(args, "action_form", "entries")
    if action_form != "entries" and backend == "rllib":
        raise ValueError(f"--action-form {action_form} trains with the sb3 backend only (RLlib's module draws one "
                         "Bernoulli per action entry)")
    scenes = tuple(args.scenes) if args.scenes else DEFAULT_TRAIN_SCENES
    check_training_scenes(scenes)
    env_kwargs = {"preset": args.preset, "num_agents": args.agents, "reward": args.reward,
                  "comm_cost_per_mb": args.comm_cost_per_mb, "comm_budget_mb": args.comm_budget_mb,
                  **({"horizon": args.horizon} if args.horizon else {})}
    factory = WorkerEnvs(scenes, args.workers, args.episodes_per_world, env_kwargs)
    config = TrainConfig(total_env_steps=args.env_steps, workers=args.workers, n_steps=args.n_steps,
                         batch_size=args.batch_size, learning_rate=args.learning_rate, ent_coef=args.ent_coef,
                         seed=args.seed, chunk_env_steps=args.chunk_env_steps, action_form=action_form)
    record = {"command": "openmulti train " + " ".join(shlex.quote(a) for a in sys.argv[2:]), "scenes": list(scenes),
              "env": env_kwargs, "title": f"{args.preset}, {args.agents} agents, cost {args.comm_cost_per_mb}/MB"
              f"{', round form' if action_form == 'round' else ''}"}
    if backend == "rllib":
        from policies.train_rllib import train_rllib  # noqa: PLC0415

        best = train_rllib(factory, config, args.out, record, address=args.ray, progress=True)
    else:
        best = train(factory, config, args.out, record, progress=True)
    print(f"[openmulti] best policy: {best} (run it: openmulti run --policy {best}); learning curve: "
          f"{args.out}/learning_curve.png, log: {args.out}/log.csv")
    return 0
