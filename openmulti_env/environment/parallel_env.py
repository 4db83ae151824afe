"""
# OpenMulti

| Import             | `from openmulti_env import parallel_env` (or `openmulti_env.openmulti_v0`) |
|--------------------|----------------------------------------------------------------------------|
| Actions            | MultiBinary                                                                |
| Parallel API       | Yes                                                                        |
| Manual Control     | No                                                                         |
| Agents             | `agents= ['agent_0', ..., 'agent_{N-1}']`                                  |
| Agents             | N = 2-8 (4 by default; preset `rl_tiny`: 2)                                 |
| Action Shape       | (2(N-1),); `round` form (1,); `instances` form ((N-1)(M+2),), M slots        |
| Action Values      | {0, 1}                                                                     |
| Observation      | Dict: `map` (S, S, 6) uint8, `comm` (8(N-1)+2,), `links` (N-1, 2) float32 in [0, 1]; `instances` (N-1, M, 9) in the instance form |
| Map Shape          | 64x64x6 (`rl`, `fast`), 48x48x6 (`rl_tiny`), 96x96x6 (`full`)                  |
| State Shape        | (map_size, map_size, 7N)                                                   |
| State Values       | uint8 [0, 255]                                                             |

N robots with RGB-D cameras walk planned paths through one simulated indoor room; each builds its own
instance-level implicit map (one small network per object, the OpenMulti paper). One env step is one
round of the collaborative learner (`mapping.team.Team.round`): every agent reads its next frames,
fuses them into its instances and trains; then the messages its action asks for cross the channel
(per-link success draws, an optional byte budget); receivers align what arrived (adopting instances
they never saw) and run parameter consistency (eq. 12) and Cross Rendering Supervision (eq. 13).

### Actions
`action_form="entries"` (the default): agent i's action has 2(N-1) entries over its peers in ascending index
order, skipping itself: entry k < N-1 is 1 to send its network parameters (per instance: vector, box,
code-book entry; the first time also a down-sampled cloud) to peer k; entry N-1+k is 1 to share its ray
directions (poses and a pixel seed, never depth) with peer k. `"round"`: one entry, everything to every peer
or nothing. `"instances"`: which instances go to which peer: per peer M = `instance_slots` entries (send the
instance in that slot of the `instances` observation), then per peer one entry "also the instances that
appear this round" (no observation could name them yet), then per peer one ray entry
(`openmulti_env.environment.actions`). Over a link that is down (`link_range_m`) nothing is sent and nothing
is paid; a link with a capacity (`link_mb_per_round`) carries what fits, in the sender's priority order, and
the rest waits.

### Observations
From the agent's own knowledge only: its frames, its fields and the messages it sent and received; never
ground truth (a test changes the world where an agent never looks and checks that its observations stay
the same bit for bit). A `Dict` (layout and meanings in `openmulti_env.environment.layout`, which policies
read by name): `map`, a top-down map of the room (rows +y, columns +x, channels last): `map_height` (top
of what its own fields hold in the column, queried on a fixed 5 cm voxel grid over the room's box, the
ceiling band left out, only near surface its instances observed), `map_decided` (share of the column its
fields decide where its instances looked), `observed` (cells its own depth has hit),
`received` (footprints of the object instances held from peers), `own_path` (path 128, current position
255), `peer_poses` (peers' last positions known from their ray messages, fading with age); `comm`, per
peer in action order what its side of the link knows (`holds`, `up_to_date`, `change` of its map since
the peer's copy, rounds since its parameters / rays last reached the peer, since the peer's parameters
last arrived, instances held from the peer, share of its bytes spent on the peer), then `budget_left` and
`progress` along its path; `links`, per peer, `up` and `room` (the share of its map a link carries in a round);
with the instance form, `instances`: per peer and slot (its instances in the link's priority order: lacked,
then most changed, then mapped by the peer too) `present`, `lacks`, `change`, `copy_age`, `shared`,
`confidence`, `size`, `age`, `bytes`. SB3 (`MultiInputPolicy`) and TorchRL take it as it is. `state()`, for
centralised critics, is every agent's `map` followed by a ground-truth plane each (the share of the cell's
observable-surface samples its map reproduces: the reward's view, in no observation).

### Rewards
The completion ratio (share of the observable ground-truth surface within 5 cm of an agent's map) is
estimated each step by probing the agent's fields along the normals of fixed surface samples
(`mapping.evaluate.probe`; its agreement with the mesh-based metric is measured in
`benchmarks/bench_env.py`). `reward="team"`: every agent gets the gain of the team's completion ratio
(the mean over agents, as the paper reports it) this step, minus `comm_cost_per_mb` x the team's
megabytes sent / N (0.01 per MB by default: at `rl_small` it puts the best fixed schedule inside the range,
`always` 0.24, `every:3` 0.39, `never` 0.14 per agent; 0 makes bytes free), minus `budget_penalty` x the
team's refused messages / N. `reward="individual"`:
its own gain, its own megabytes and refused messages. Ratios are fractions (0-1): an episode's return
without costs is the final completion ratio. `reward_baseline="never_always"` puts every world on one scale:
the same episode is played once with `never` and once with `always` (cached on disk), a step pays its gain
less `never`'s at that step over what `always` adds by the end, minus `comm_cost_of_always` (0.3) x its
share of `always`'s bytes; `never` returns 0 and `always` 0.7 in every world (`environment.rewards`).
`reward_baseline="front"` prices bytes by the episode's fixed-rate front instead (`every:K`, `rate:Q` played
and cached too): the return is the margin over the front at the team's bytes (`environment.reward_front`).

### Episode
Termination when every path is read (`rl`, `fast`: 24 steps, `rl_tiny`: 8, `demo`: 12, `full`: 20): the
episode's real end, so a trainer bootstraps no value past it; truncation after `horizon` steps. `infos[agent]` always holds the same numeric keys: `completion_ratio` (percent),
`completion_gain` (percent points), `bytes_sent`, `bytes_received` (this step), `bytes_sent_total`,
`budget_left_mb` (inf without a budget), `messages_delivered`, `messages_dropped`,
`messages_refused` (its own messages this step), `instances`, `instances_received`, `step`.
`episode="recorded"`: each episode replays a real `never` episode recorded once per world and models what the
actions change (`mapping.team.recorded`, docs/recorded.md): the same spaces, rewards and infos, 100x cheaper.

### Seeds
The constructor's `seed` fixes the world (room layout and paths; default 0), so an env's episodes share a
room and its cached geometry; `reset(seed=k)` fixes an episode (segmentation errors, channel draws,
network initialisation, ray sampling). Same seeds, same actions: the same episode.

### Arguments
```python
parallel_env(scene=None, num_agents=None, preset="rl", seed=None, render_mode=None,
             comm_budget_mb=None, reward="team", max_cycles=None, **overrides)
```
`scene`: a scene preset name, `random:SEED` or a manifest path (default: the preset's, room0; `rl_tiny`:
the small `tiny` room). `num_agents`: 2-8 (default: the preset's). `preset`: one of the table in
`openmulti_env.experiment.presets`, the same episodes as `openmulti run --preset`: `rl` (the default, RL-sized: 24
steps of about a second), `rl_tiny` (8 steps, for tests), `tiny`, `demo`, `fast`, `full` (the paper's).
`seed`: the world's seed. `render_mode`: None or `rgb_array` (`human` is accepted and draws nothing:
the env is headless). `comm_budget_mb`: megabytes each agent may send per episode. `reward`: `team` or
`individual`. `max_cycles`: the horizon (PettingZoo's name for `horizon`). `overrides`: any field of the configuration
tree (`openmulti_env.experiment.Experiment`, the one `openmulti run` writes as `config.yaml`), by its short
spelling (e.g. `success_probability=0.5`, `comm_cost_per_mb=0`, `action_form="instances"`, `instance_slots=16`,
`link_range_m=2.0`, `link_mb_per_round=0.25`, `consistency="dinno"`, `map_size=96`,
`threads=1`, `cache_dir=...`; `openmulti_env.experiment.overrides.ALIASES`) or by its dotted path with `__`
for the dots (`team__exchange__float16=True`). `env.config` is the episode's whole tree.

### Version History
* v0: first release (openmulti 0.1). 2026-12-06: `map_height`, `map_decided` and the reward's completion
  estimate read only surface the agent's instances observed (docs/observed_space.md); shapes unchanged.
  2026-12-06 (observation version 2): `links` added, `instances` and the `round` / `instances` action forms,
  `link_range_m` / `link_mb_per_round`, 0.01 per MB by default, the paths' end is termination; `map` and
  `comm` unchanged (the shipped policy reads only them). A seed's frames are the same in every env and
  process (pyrender's draw and light order fixed by name; they were one pixel apart before).
"""

from __future__ import annotations

import time
import warnings

import numpy as np
from gymnasium import spaces
from gymnasium.utils import EzPickle, seeding
from pettingzoo import ParallelEnv
from pettingzoo.utils import parallel_to_aec, wrappers

from mapping.perception import shared_text_encoder
from mapping.runtime import torch_threads
from mapping.team import Team
from openmulti_env.environment.actions import ActionError, action_size, actions_to_plan
from openmulti_env.environment.config import DEFAULT_PRESET, env_config, env_workers, pettingzoo_arguments
from openmulti_env.experiment import Experiment
from openmulti_env.environment.rewards import EpisodeRewards, RewardBaselines, play_fixed
from openmulti_env.environment.render import team_picture
from openmulti_env.environment.recorded_episode import RecordedEpisodes
from openmulti_env.environment.observation import ProbeRaster, observed_slots, slot_instances, team_observer
from openmulti_env.world.cache import cached_world
from openmulti_env.world.stream import RenderCache, world_streams, world_vocabulary
from openmulti_env.environment.layout import INSTANCE_FEATURES, LINK_STATE, MAP_CHANNELS, comm_size

INFO_KEYS = ("completion_ratio", "completion_gain", "bytes_sent", "bytes_received", "bytes_sent_total",
             "budget_left_mb", "messages_delivered", "messages_dropped", "messages_refused", "instances",
             "instances_received", "step")
RENDER_MODES = ("rgb_array",)


class OpenMultiParallelEnv(ParallelEnv, EzPickle):
    """The collaborative mapper as a PettingZoo ParallelEnv (see the module docstring)."""

    metadata = {"name": "openmulti_v0", "render_modes": list(RENDER_MODES), "render_fps": 2,
                "is_parallelizable": True}

    def __init__(self, scene: str | None = None, num_agents: int | None = None, preset: str = DEFAULT_PRESET,
                 seed: int | None = None, render_mode: str | None = None, comm_budget_mb: float | None = None,
                 reward: str = "team", max_cycles: int | None = None, **overrides):
        EzPickle.__init__(self, scene=scene, num_agents=num_agents, preset=preset, seed=seed, render_mode=render_mode,
                          comm_budget_mb=comm_budget_mb, reward=reward, max_cycles=max_cycles, **overrides)
        num_agents, overrides = pettingzoo_arguments(num_agents, max_cycles, overrides)
        self.config: Experiment = env_config(preset, scene=scene, agents=num_agents, comm_budget_mb=comm_budget_mb,
                                            reward=reward, **overrides)
        if render_mode is not None and render_mode not in RENDER_MODES + ("human",):
            raise ValueError(f"unknown render_mode {render_mode!r}; choose None or one of {list(RENDER_MODES)}")
        if render_mode == "human":
            warnings.warn("openmulti_v0 is headless: render_mode='human' draws nothing (render() returns None); "
                          "use render_mode='rgb_array' for pictures", stacklevel=2)
        self.render_mode = render_mode
        self.preset = preset
        self.world_seed = 0 if seed is None else int(seed)
        n = self.config.num_agents
        self.possible_agents = [f"agent_{i}" for i in range(n)]
        self.agents: list[str] = []
        size = self.config.env.map_size
        env_cfg = self.config.env
        parts = {"map": spaces.Box(0, 255, (size, size, len(MAP_CHANNELS)), np.uint8),
                 "comm": spaces.Box(0.0, 1.0, (comm_size(n),), np.float32),
                 "links": spaces.Box(0.0, 1.0, (n - 1, len(LINK_STATE)), np.float32)}
        self._slots = observed_slots(env_cfg, env_cfg.action_form)
        if self._slots:
            parts["instances"] = spaces.Box(0.0, 1.0, (n - 1, self._slots, len(INSTANCE_FEATURES)), np.float32)
        self._observation_space = spaces.Dict(parts)
        self._action_space = spaces.MultiBinary(action_size(env_cfg.action_form, n, self._slots))
        self.state_space = spaces.Box(0, 255, (size, size, (len(MAP_CHANNELS) + 1) * n), np.uint8)
        self._episode_rng, _ = seeding.np_random(seed)
        self.world = None
        self.team: Team | None = None
        self._rewarder: EpisodeRewards | None = None
        self.timings: dict[str, float] = {}
        self.last_cache_hit: bool | None = None

    # ---- spaces (the same objects on every call) ---------------------------------------------------
    def observation_space(self, agent: str) -> spaces.Dict:
        self._check_agent(agent)
        return self._observation_space

    def action_space(self, agent: str) -> spaces.MultiBinary:
        self._check_agent(agent)
        return self._action_space

    def _check_agent(self, agent: str) -> None:
        if agent not in self.possible_agents:
            raise KeyError(f"unknown agent {agent!r}; the agents are {self.possible_agents}")

    # ---- episode -------------------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None):
        """A fresh team on the env's world; ``seed`` fixes the episode. ``options`` are not used. Torch
        runs on ``threads`` threads inside reset and step only (the caller's setting is kept)."""
        with torch_threads(self.config.run.threads):
            return self._reset(seed)

    def _reset(self, seed: int | None):
        start = time.perf_counter()
        if seed is not None:
            self._episode_rng, _ = seeding.np_random(seed)
        episode_seed = int(self._episode_rng.integers(2**31 - 1))
        self._build_world()
        if self.team is not None:  # freed here by reference counting: a team holds no reference cycles
            self.team.release()  # (tested), so no full garbage collection (130 ms a reset) is needed
            self.team = None
        self._rewarder.start(episode_seed)
        self.team = self._new_team(episode_seed)
        self._snapshots = self.team.snapshots()
        self.agents = list(self.possible_agents)
        self.steps = 0
        self._observer.reset(len(self.agents))
        self._completion = np.zeros(len(self.agents))
        self._covered = [np.zeros(len(self._probe_points), bool) for _ in self.agents]
        self._links = (np.zeros((len(self.agents),) * 2, bool),) * 2
        self._last_report = None
        observations = {a: self._observe(i) for i, a in enumerate(self.agents)}
        infos = {a: self._info(i, None, 0.0) for i, a in enumerate(self.agents)}
        self.timings = {"reset_s": time.perf_counter() - start}
        return observations, infos

    def _new_team(self, episode_seed: int):
        """The episode's team: the real mapper, or with ``episode="recorded"`` a ``RecordedTeam``."""
        if self._recorded is not None:
            team = self._recorded.team(episode_seed)
            if self._recorded.complete:  # every recording made: frames, GL and the culled surface are not used again
                self._recorded.release(self.world, self._frames)
            return team
        return self._real_team(episode_seed)

    def _real_team(self, episode_seed: int) -> Team:
        cfg = self.config
        encoder = shared_text_encoder(name=cfg.perception.text_encoder, persist=True)
        streams = world_streams(self.world, episode_seed, cfg.perception.segmentation_errors, text_encoder=encoder,
                                render=self._frames.render)
        if self._vocabulary is None:
            self._vocabulary = world_vocabulary(self.world, encoder)
        return Team(streams, cfg.team, self._vocabulary, seed=episode_seed, channel=cfg.channel, device=cfg.run.device,
                    workers=env_workers(cfg), processes=cfg.run.processes, learner=cfg.run.learner)

    @property
    def recorded_episodes(self) -> RecordedEpisodes | None:
        """With ``episode="recorded"``: the world's recordings (their real teams and probes, for checks)."""
        return self._recorded

    def _fixed_player(self):
        """``play(episode_seed, schedule)`` of a fixed schedule on this env's world (the reward's baselines)."""
        return lambda seed, schedule: play_fixed(lambda: self._new_team(seed), self.config.num_agents,
                                                 self.config.env.horizon, self._probe_points, self._probe_normals,
                                                 schedule, seed)

    def _build_world(self) -> None:
        """The world once per env (cached on disk across envs and processes), with its probes and grid."""
        if self.world is not None:
            return
        cfg = self.config
        self.world, self.last_cache_hit = cached_world(cfg.scene, self.world_seed, cfg.world,
                                                       cfg.env.cache_dir, cfg.env.cache_max_mb)
        points, normals, ids = self.world.surface.sample_points(cfg.env.probe_points, seed=self.world_seed)
        self._probe_points, self._probe_normals = points, normals
        size = np.asarray(self.world.scene.size_m, float)
        self._observer = team_observer(cfg, size, cfg.env.action_form)
        self._grid = self._observer.grid
        ceiling = [inst.instance_id for inst in self.world.scene.instances if inst.category == "ceiling"]
        self._probes = ProbeRaster(self._grid, points, hidden=np.isin(ids, ceiling))
        floor = np.zeros(cfg.env.map_size ** 2, np.uint8)
        floor[self._probes.flat] = 255
        self._floor = floor.reshape(cfg.env.map_size, cfg.env.map_size)
        self._vocabulary = None
        self._frames = RenderCache(self.world, cfg.env.frame_cache_mb)
        self._recorded = RecordedEpisodes(cfg, self.world_seed, self._real_team, points, normals, self._observer) \
            if cfg.env.episode == "recorded" else None
        self._rewarder = EpisodeRewards(cfg.env, RewardBaselines(cfg, self.world_seed, self._fixed_player())
                                        if cfg.env.reward_baseline != "none" else None)

    def step(self, actions: dict):
        with torch_threads(self.config.run.threads):
            return self._step(actions)

    def _step(self, actions: dict):
        if self.team is None:
            raise RuntimeError("call reset() before step()")
        if not self.agents:
            raise RuntimeError("the episode has ended (every agent is terminated or truncated); call reset() to start another")
        t0 = time.perf_counter()
        try:
            slot_ids = [slot_instances(s, len(self.agents), self._slots) for s in self._snapshots] if self._slots else None
            plan = actions_to_plan(actions, self.agents, self.config.env.action_form, self._slots, slot_ids)
        except ActionError as exc:
            raise ActionError(f"{exc} (action space of each agent: {self._action_space})") from None
        report = self.team.round(plan)
        self._snapshots = report.agents
        t1 = time.perf_counter()
        gains = np.zeros(len(self.agents))
        self._covered = self.team.surface_coverage(self._probe_points, self._probe_normals)
        for i in range(len(self.agents)):
            ratio = float(np.mean(self._covered[i]))
            gains[i], self._completion[i] = ratio - self._completion[i], ratio
        t2 = time.perf_counter()
        rewards = self._rewards(report, gains)
        self.steps += 1
        self._links = (plan.send_params, plan.share_rays)
        self._last_report = report
        self._observer.update(self.team, self._snapshots)
        observations = {a: self._observe(i) for i, a in enumerate(self.agents)}
        t3 = time.perf_counter()
        infos = {a: self._info(i, report, 100.0 * gains[i]) for i, a in enumerate(self.agents)}
        ended = self.team.done or (self.config.env.horizon is not None and self.steps >= self.config.env.horizon)
        terminations = {a: bool(self.team.done) for a in self.agents}  # the paths end: the episode's real end
        truncations = {a: bool(ended and not self.team.done) for a in self.agents}  # cut short by the horizon
        if ended:
            self.agents = []
        self.timings = {"learner_s": t1 - t0 - report.exchange_s, "exchange_s": report.exchange_s,
                        "reward_s": t2 - t1, "observation_s": t3 - t2,
                        "local_s": float(sum(report.local_s)), "consistency_s": float(sum(report.consistency_s))}
        return observations, rewards, terminations, truncations, infos

    def _rewards(self, report, gains: np.ndarray) -> dict[str, float]:
        mb = np.asarray(report.bytes_sent, float) / 1e6
        refused = np.asarray([snapshot.messages["over_budget"] for snapshot in report.agents], float)
        values = self._rewarder.step(gains, mb, refused, self.steps + 1)
        return {a: float(values[i]) for i, a in enumerate(self.possible_agents)}

    # ---- observations, infos, state ----------------------------------------------------------------
    def _observe(self, i: int) -> dict[str, np.ndarray]:
        """Agent i's observation from its snapshot and its own fields (never ground truth)."""
        return self._observer.observe(self._snapshots[i])

    def _info(self, i: int, report, gain_pct: float) -> dict[str, float]:
        snapshot = self._snapshots[i]
        info = {"completion_ratio": 100.0 * float(self._completion[i]), "completion_gain": float(gain_pct),
                "bytes_sent": float(snapshot.bytes_sent), "bytes_received": float(snapshot.bytes_received),
                "bytes_sent_total": float(snapshot.bytes_sent_total),
                "budget_left_mb": float(snapshot.budget_left_bytes / 1e6),
                "messages_delivered": float(snapshot.messages["delivered"]),
                "messages_dropped": float(snapshot.messages["dropped"]),
                "messages_refused": float(snapshot.messages["over_budget"]),
                "instances": float(snapshot.instances),
                "instances_received": float(snapshot.instances - snapshot.instances_own),
                "step": float(self.steps)}
        assert tuple(info) == INFO_KEYS
        return info

    def slot_instance_ids(self, agent: str) -> np.ndarray:
        """With ``action_form="instances"``: (N - 1, M) int64, the id of the agent's own instance each slot of its
        observation (and action) holds now, peers in action order, -1 where a slot is empty. For analysis and
        hindsight baselines (an instance's id is the agent's own label, not part of any observation)."""
        self._check_agent(agent)
        if not self._slots:
            raise ValueError(f"slot_instance_ids needs action_form='instances' (this env's is "
                             f"{self.config.env.action_form!r})")
        if self.team is None:
            raise RuntimeError("call reset() before slot_instance_ids()")
        i = self.possible_agents.index(agent)
        out = np.full((len(self.possible_agents) - 1, self._slots), -1, np.int64)
        for k, ids in enumerate(slot_instances(self._snapshots[i], len(self.possible_agents), self._slots)):
            out[k, :len(ids)] = ids
        return out

    def state(self) -> np.ndarray:
        """For centralised critics: every agent's ``map`` planes, each followed by a ground-truth plane (the
        share of the cell's observable-surface samples its map reproduces, the reward's view; never in an
        observation): (map_size, map_size, 7N) uint8."""
        if self.team is None:
            raise RuntimeError("call reset() before state()")
        return np.concatenate([np.concatenate([self._observe(i)["map"], self._probes.coverage(self._covered[i])[..., None]],
                                              axis=-1) for i in range(len(self.possible_agents))], axis=-1)

    # ---- pictures ----------------------------------------------------------------------------------
    def render(self, mode: str | None = None):
        """``rgb_array``: (192, W, 3) uint8, the agents' maps then the team panel; None otherwise.

        ``mode`` is for clients that pass one (RLlib's ``ParallelPettingZooEnv`` calls ``render(mode)``):
        ``"rgb_array"`` draws whatever the env was made with."""
        if mode == "rgb_array" and self.render_mode is None:
            self.render_mode = "rgb_array"
        if self.render_mode is None:
            warnings.warn("render() called with render_mode=None; make the env with render_mode='rgb_array'",
                          stacklevel=2)
            return None
        if self.render_mode != "rgb_array" or self.team is None:
            return None
        maps = [self._observe(i)["map"] for i in range(len(self.possible_agents))]
        walked = [poses[:snapshot.frames_read] for poses, snapshot in zip(self.world.agent_poses, self._snapshots)]
        return team_picture(maps, self._grid, self._floor, walked, self._links)

    def close(self) -> None:
        if self.team is not None:
            self.team.release()
        if self.world is not None:
            self.world.close()


def parallel_env(**kwargs) -> OpenMultiParallelEnv:
    """The native parallel env (keywords as ``OpenMultiParallelEnv``)."""
    return OpenMultiParallelEnv(**kwargs)


def raw_env(**kwargs):
    """The AEC form through PettingZoo's conversion."""
    return parallel_to_aec(parallel_env(**kwargs))


def env(**kwargs):
    """The AEC form with PettingZoo's standard wrappers (an action out of bounds or given to a dead agent is
    an error, ``render`` and ``observe`` before ``reset`` are refused)."""
    wrapped = raw_env(**kwargs)
    wrapped = wrappers.AssertOutOfBoundsWrapper(wrapped)
    return wrappers.OrderEnforcingWrapper(wrapped)
