"""The ``openmulti`` command line: ``scenes``, ``run`` (a team maps a scene or a data set round by round under a
scripted communication policy), ``query``, ``reproduce`` (the paper's tables), ``train`` (a communication policy)
and ``cache``.

Heavy modules (torch, open3d, the world) are imported inside the commands that need them, so that
``openmulti query`` starts fast."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from mapping.perception.image_encoder import ImageEncoderError
from mapping.perception.text_encoder import TextEncoderError
from openmulti_env.experiment import CONFIG_NAME, ConfigError, Experiment, experiment, read_config
from openmulti_env.experiment.options import (TRAIN_DEST, add_dataclass_options, add_tree_options, normalise_argv,
                                              spelled_for_command_line,
                                              tree_overrides, typed_overrides)
from openmulti_env.experiment.presets import PRESET_NAMES, default_preset
from openmulti_env.experiment.tree import DEFAULT_PRESETS
from openmulti_env.world.world import MAX_AGENTS
from policies.train import TrainConfig

RUN_SHORT = ("scene", "agents", "policy", "seed", "out", "device", "threads", "workers", "processes", "alignment",
             "consistency", "no_cross_rendering", "comm_budget_mb", "link_range_m", "link_mb_per_round",
             "no_evaluation", "data", "kind", "gt_mesh", "frames", "intrinsics", "depth_scale", "segmenter",
             "holdout_every")
"""The short spellings ``openmulti run`` offers besides every ``--node.field`` (the README's)."""
TRAIN_SHORT = ("agents", "reward", "reward_baseline", "comm_cost_of_always", "comm_cost_per_mb", "comm_budget_mb", "horizon",
               "link_range_m", "link_mb_per_round", "episode", "recordings")
"""The short spellings of the env's settings ``openmulti train`` offers."""
RUN_HELP = """Every setting of a run is one configuration tree (a preset plus these options); the run writes it
whole as OUT/config.yaml, and `openmulti run --config OUT/config.yaml --out NEW` repeats the run. Each field
of the tree is an option --node.field (e.g. --team.exchange.float16, --team.consistency.rho 0.3); the common
ones have the short spellings of the first group. The value in brackets is the `fast` preset's."""

class _DefaultsShown(argparse.HelpFormatter):
    """Help that ends with the option's default, where it has one worth saying (not None or a flag's)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        unsaid = default is None or default is False or default is True or default == argparse.SUPPRESS
        if "default" in text or unsaid or not action.option_strings:
            return text
        return f"{text} (default: {default})"


class _RawDefaults(argparse.RawDescriptionHelpFormatter, _DefaultsShown):
    """The description as written (it holds commands), defaults shown."""


def _agents(value: str) -> int:
    n = int(value)
    if not 1 <= n <= MAX_AGENTS:
        raise argparse.ArgumentTypeError(f"--agents must be between 1 and {MAX_AGENTS}, got {n}")
    return n


def cmd_scenes(args: argparse.Namespace) -> int:
    """List presets, or describe one scene with its coverage (and optionally render pictures)."""
    from openmulti_env.experiment.presets import world_config  # noqa: PLC0415
    from openmulti_env.world import World, list_presets  # noqa: PLC0415
    from openmulti_env.world.presets import PRESETS  # noqa: PLC0415

    if args.scene is None:
        for name in list_presets():
            print(f"{name:<9} {PRESETS[name]}")
        print("also: random:SEED, or a path to a .json/.yaml manifest of your own meshes")
        return 0
    world = World.build(args.scene, seed=args.seed, config=world_config(args.preset, args.agents))
    report = world.coverage()
    info = {**world.scene.describe(), "agents": args.agents,
            "frames_per_agent": [len(p) for p in world.agent_poses],
            "observable_area_share": round(world.surface.visible_fraction, 4), "coverage": report.as_dict()}
    if args.render:
        from openmulti_env.world.plots import save_frames, save_world_overview  # noqa: PLC0415

        out = Path(args.render)
        gt, _, _ = world.surface.sample_points(20000, seed=args.seed)
        save_world_overview(out / "top_down.png", world.scene, world.agent_poses, gt, world.caster, world.intrinsics)
        for a, poses in enumerate(world.agent_poses):
            idx = np.linspace(0, len(poses) - 1, 3).astype(int)
            save_frames(out / f"frames_agent_{a}.png", [world.render(a, int(i)) for i in idx], f"agent_{a}")
        info["render_dir"] = str(out)
    if args.export:
        from openmulti_env.world.export import export_world  # noqa: PLC0415

        info["export_dir"] = str(export_world(world, args.export, args.layout))
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        print(f"{world.scene.name}: {len(world.scene.instances)} instances, room {info['size_m']} m")
        for inst in info["instances"]:
            print(f"  {inst['id']:>3}  {inst['category']:<13} {inst['caption']}")
        cov = info["coverage"]
        print(f"coverage per agent {cov['per_agent_pct']} %, union {cov['union_pct']} %")
        if args.export:
            print(f"exported as a {args.layout} data set to {info['export_dir']}")
    world.close()
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    """The main job: the team maps the scene (or ``--data``) round by round under the policy; prints a
    results table."""
    from mapping.pipeline.summary import results_table  # noqa: PLC0415
    from mapping.pipeline.runner import RunResult  # noqa: PLC0415
    from openmulti_env.runs.run import run_experiment  # noqa: PLC0415

    tree = experiment_from_args(args)
    out = Path(tree.run.out)
    what = f"scene {tree.scene}" if tree.data.path is None else f"data {tree.data.path}"
    print(f"[openmulti] {what}, {tree.num_agents} agents, preset {tree.preset}, seed {tree.seed}, "
          f"policy {tree.run.policy}, alignment {'paper' if tree.team.alignment else 'none'}, consistency "
          f"{tree.team.consistency.algorithm}{'' if tree.team.consistency.cross_rendering else ', no cross rendering'}")
    metrics = run_experiment(tree)
    fields = set(RunResult.__dataclass_fields__) - {"extra"}
    result = RunResult(**{k: v for k, v in metrics.items() if k in fields},
                       extra={k: v for k, v in metrics.items() if k not in fields})
    print()
    print("\n".join(results_table(result, out)))
    print(f"Settings: {out / CONFIG_NAME} (openmulti run --config {out / CONFIG_NAME} --out NEW repeats the run)")
    return 0


def experiment_from_args(args: argparse.Namespace):
    """The run's tree: ``--config``'s (or ``--preset``'s, ``DEFAULT_PRESETS["run"]`` by default) with the command
    line's overrides."""
    if args.config is not None and args.preset:
        raise ValueError("give --config FILE or --preset NAME, not both (the file's tree names its preset)")
    overrides = typed_overrides(tree_overrides(args), Experiment)
    base = read_config(args.config) if args.config is not None else None  # --config= is refused, not ignored
    return experiment(args.preset or DEFAULT_PRESETS["run"], overrides, base=base)


def cmd_query(args: argparse.Namespace) -> int:
    """Rank a run's instances against one query (or every line of --queries FILE); print JSON.

    The code books are encoded once for all queries; ``--plot`` also writes DIR/plots/query_<slug>.png.
    """
    from openmulti_env.runs.query import RunMap, image_encoder_or_none, run_query  # noqa: PLC0415

    texts = [args.text] if args.text is not None else []
    if args.queries:
        texts += [line.strip() for line in Path(args.queries).read_text().splitlines()
                  if line.strip() and not line.lstrip().startswith("#")]
    if not texts:
        raise ValueError('give a query text or --queries FILE, e.g. openmulti query --run DIR "somewhere to sleep"')
    run_map = RunMap(args.run, args.text_encoder, image_encoder_or_none(args.clip_checkpoint))
    payloads = [run_query(args.run, t, top_k=args.top, plot=args.plot, run_map=run_map).payload for t in texts]
    print(json.dumps(payloads[0] if args.queries is None else payloads, indent=2))
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    """Run the runs of one of the paper's tables (or all) and write DIR/T.json, DIR/T.md, DIR/T.png."""
    from openmulti_env.runs.reproduce.command import reproduce  # noqa: PLC0415

    written = reproduce(args.table, args.scenes, args.seeds, args.preset, args.out, agents=args.agents,
                        threads=args.threads, device=args.device, three_cullings=not args.free_space_only,
                        methods=args.methods, run_missing=not args.tables_only, ray_address=args.ray,
                        success_rates=args.success_rates)
    for name, rows in written.items():
        if rows:
            print(Path(args.out, f"{name}.md").read_text())
    done = [n for n, rows in written.items() if rows]
    print(f"Wrote {', '.join(f'{args.out}/{n}.json' for n in done)} (+ .md, .png)" if done else "Wrote no table: no run is finished")
    return 0


def cmd_cache(args: argparse.Namespace) -> int:
    """Report (or clear) the env's cache of world geometry."""
    from openmulti_env.world.cache import clear_world_cache, world_cache_dir  # noqa: PLC0415

    folder = world_cache_dir(args.dir)
    if args.clear:
        freed = clear_world_cache(args.dir)
        print(f"cleared {folder}: {freed / 1e6:.1f} MB freed")
        return 0
    entries = sorted(folder.glob("*.npz")) if folder.is_dir() else []
    print(f"{folder}: {len(entries)} world(s), {sum(p.stat().st_size for p in entries) / 1e6:.1f} MB "
          "(openmulti cache --clear empties it)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of the ``openmulti`` command."""
    parser = argparse.ArgumentParser(prog="openmulti", description="OpenMulti multi-agent implicit mapping",
                                     formatter_class=_DefaultsShown)
    sub = parser.add_subparsers(dest="command", required=True)

    fmt = _DefaultsShown
    p = sub.add_parser("scenes", help="list presets, or describe one scene and its coverage", formatter_class=fmt)
    p.add_argument("scene", nargs="?", help="preset name, random:SEED or manifest path (none: list the presets)")
    p.add_argument("--agents", type=_agents, default=4, help="agents (one path each)")
    p.add_argument("--seed", type=int, default=0, help="layout and paths seed (0: the canonical room)")
    p.add_argument("--preset", choices=PRESET_NAMES, default=DEFAULT_PRESETS["run"],
                   help="episode size (frames, image size)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--render", metavar="DIR", help="write a top-down picture and a few frames per agent")
    p.add_argument("--export", metavar="DIR", help="write the world as an RGB-D data set (frames of all agents)")
    p.add_argument("--layout", choices=("replica", "scannet", "nice_slam"), default="replica",
                   help="data set layout of --export")
    p.set_defaults(func=cmd_scenes)

    p = sub.add_parser("run", help="a multi-agent team run on one scene (--scene) or a real RGB-D data set (--data)",
                       formatter_class=fmt, description=RUN_HELP,
                       usage="openmulti run [--preset P | --config FILE] [--scene S | --data DIR] [--agents N] "
                             "[--policy P] [--seed K] [--out DIR] [--NODE.FIELD VALUE ...]")
    p.add_argument("--config", metavar="FILE", help="a configuration tree (a run's config.yaml, a .json, or a run's "
                   "metrics.json): repeat that run (give --out NEW), the options below change it")
    p.add_argument("--preset", choices=PRESET_NAMES, help="the tree to start from: tiny (smoke), demo (make demo), "
                   "fast (default), full (the paper's), rl_tiny, rl_small, rl (the env's RL-sized ones)")
    add_tree_options(p, Experiment, shown=default_preset("run"), short=RUN_SHORT, skip=("preset", "env"))
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("query", help="open-vocabulary instance retrieval on a finished run", formatter_class=fmt)
    p.add_argument("text", metavar="TEXT", nargs="?", help='what to look for, e.g. "somewhere to sleep"')
    p.add_argument("--queries", metavar="FILE", help="one query per line (# comments): prints a JSON list")
    p.add_argument("--run", required=True, metavar="DIR", help="run directory (with codebook/ and meshes/)")
    p.add_argument("--top", type=int, default=5, metavar="K", help="how many instances to print")
    p.add_argument("--clip-checkpoint", metavar="PATH", help="local image-text (CLIP) checkpoint: adds the visual term")
    p.add_argument("--text-encoder", choices=("mpnet", "minilm"),
                   help="text encoder (default: the one the run's code books record; another is refused)")
    p.add_argument("--plot", action="store_true", help="also write DIR/plots/query_<slug>.png (about a second more)")
    p.set_defaults(func=cmd_query)

    p = sub.add_parser("reproduce", help="the paper's experiments: Tables I and III-VI (and the semantic table)",
                       formatter_class=fmt)
    p.add_argument("--table", required=True, help="geometric, multi-vs-single, semantic, ablation, comm-failure, "
                   "transmission, all (the paper's six), tradeoff (completion against MB of every scripted "
                   "policy and the learned one), or schedules (the trade-off of the instance-level and fixed "
                   "policies in three link scenarios: unlimited, a 2 m range, 0.25 MB per link and round; "
                   "--preset rl_small for its cheap part)")
    p.add_argument("--scenes", nargs="+", metavar="S", help="scenes of the grid (default: room0; tradeoff: room0 "
                   "office0 room2; schedules: room1)")
    p.add_argument("--seeds", nargs="+", type=int, default=[0], metavar="K", help="seeds of the grid")
    p.add_argument("--preset", choices=PRESET_NAMES, default=DEFAULT_PRESETS["reproduce"], help="episode size of every run")
    p.add_argument("--agents", type=_agents, default=4, help="agents of the team methods (single_agent has 1)")
    p.add_argument("--out", default="runs/reproduce", metavar="DIR",
                   help="folder of the tables, rows and runs (started again, finished runs are reused; the same "
                        "command started twice shares the grid, each run made once)")
    p.add_argument("--threads", type=int, default=1,
                   help="torch threads per run (runs go one at a time; with --ray, the CPUs each task asks for)")
    p.add_argument("--ray", nargs="?", const="local", metavar="ADDRESS",
                   help="run the grid's missing runs as Ray tasks: alone, on a Ray started on this machine; with "
                        "an address (ray://HOST:10001, HOST:6379 or auto), on that cluster. Rows land in the same "
                        "DIR/rows/ (a grid resumes, and can be split between a cluster and a laptop). Needs "
                        "pip install 'openmulti[ray]'")
    p.add_argument("--device", default="cpu", help="cpu, cuda or auto")
    p.add_argument("--free-space-only", action="store_true",
                   help="score with today's free-space culling only (skip the NICE-SLAM and unculled scores)")
    p.add_argument("--methods", nargs="+", metavar="M",
                   help="run only these of the table's methods (tradeoff, schedules: these policies)")
    p.add_argument("--success-rates", nargs="+", type=float, metavar="P",
                   help="run only the runs at these link success rates (comm-failure: 1 0.8 0.5 0.2; e.g. 0.2 "
                        "first, the column Table V's ordering is decided on)")
    p.add_argument("--tables-only", action="store_true",
                   help="make no run: write the tables from the runs already finished (missing ones are named)")
    p.set_defaults(func=cmd_reproduce)

    p = sub.add_parser("cache", help="the env's world-geometry cache: where it is, its size, --clear",
                       formatter_class=fmt)
    p.add_argument("--dir", metavar="DIR", help="cache folder (default: $OPENMULTI_CACHE/worlds or ~/.cache/openmulti/worlds)")
    p.add_argument("--clear", action="store_true", help="delete every cached world")
    p.set_defaults(func=cmd_cache)

    p = sub.add_parser("train", help="learn a shared communication policy with PPO (SB3, or RLlib on Ray) on the env",
                       formatter_class=_RawDefaults, description=TRAIN_HELP,
                       usage="openmulti train [--preset P | --config FILE] [--scenes S ...] [--env-steps N] "
                             "[--workers N] [--backend sb3|rllib] [--out DIR] [--FIELD VALUE ...] [--NODE.FIELD VALUE ...]")
    p.add_argument("--out", default="runs/train", help="folder of the run: checkpoint (resumed), log.csv, "
                   "learning_curve.png, best.json/.safetensors and latest.json/.safetensors")
    p.add_argument("--config", metavar="FILE", help="the env's configuration tree (a run's config.yaml or a .json): "
                   "every episode's settings; the options below change it")
    p.add_argument("--preset", choices=PRESET_NAMES, help="the env's preset (default rl_small)")
    p.add_argument("--scenes", nargs="+", metavar="SCENE", help="training worlds (default: random:100 .. random:115; "
                   "room0, office0 and room2 are held out for the trade-off table)")
    p.add_argument("--episodes-per-world", type=int, default=2, help="episodes before a worker moves to its next world")
    p.add_argument("--episode-seeds", type=int, metavar="K", help="play each world's episodes from K episode seeds "
                   "(0..K-1) in turn, so that a world's baselines (--reward-baseline never_always or front) are "
                   "played once per seed and then read from the cache (default: a fresh seed every episode)")
    p.add_argument("--backend", choices=("sb3", "rllib"), default="sb3",
                   help="sb3: Stable-Baselines3 PPO in worker processes here; rllib: RLlib's multi-agent PPO, its env "
                        "runners on a local Ray or on --ray ADDRESS (pip install 'openmulti[ray]')")
    p.add_argument("--ray", metavar="ADDRESS", help="with --backend rllib: the Ray cluster's address (ray://HOST:10001, "
                   "HOST:6379 or auto; default: a Ray started on this machine)")
    add_dataclass_options(p, TrainConfig, prefix=TRAIN_DEST, title="PPO and the run's size (policies.train.TrainConfig)",
                          also={"env_steps": "total_env_steps"})
    add_tree_options(p, Experiment, shown=default_preset("train"), short=TRAIN_SHORT,
                     skip=("preset", "scene", "seed", "run", "data", "global_map"))
    p.set_defaults(func=cmd_train)
    return parser


def cmd_train(args: argparse.Namespace) -> int:
    """Train a communication policy (``openmulti_env.runs.train``)."""
    from openmulti_env.runs.train import train_command  # noqa: PLC0415

    return train_command(args)


TRAIN_HELP = """Learn one communication policy shared by every agent (PPO from Stable-Baselines3, parameter
sharing through SuperSuit; or RLlib's multi-agent PPO with --backend rllib) on a distribution of worlds, with the reward's cost per MB sent. The run is
resumable (the same --out continues it) and writes the best policy as a .json + .safetensors pair that
`openmulti run --policy FILE` and `policies.make_policy(FILE, N)` load.

On a laptop (2 cores): a smoke run in minutes,
  openmulti train --preset rl_tiny --agents 2 --env-steps 256 --workers 1 --out runs/train_smoke
and the shipped policy's run (about an hour; policies/trained/README.md records it),
  openmulti train --preset rl_small --env-steps 4096 --workers 2 --comm-cost-per-mb 0.01 --out runs/train_rl_small
--workers is at most one per core; --worlds-per-worker K steps K worlds in each worker in turn (more worlds per
update, not more steps per hour: peak 1.13 GB for one rl_small world in a process, 0.87 GB each for two, 0.63 GB
each for four; docs/profile.md), e.g. --workers 2 --worlds-per-worker 2 on 8 GB. --preset rl_lite is 12 steps on
shorter tours, 1.5x faster (about 3,000-4,800 env steps an hour here against 2,000 at rl_small); --episode recorded
replays a real episode recorded once per world and models what the actions change (about 180,000 env steps an hour
at rl_lite; a model: docs/recorded.md); how each ranks schedules against `fast`: docs/transfer.md.
Learning a schedule (docs/learning.md): the team decides once a round from every agent's observation, a
central critic reads state(), the reward is normalised per episode against never/always (cached), TensorBoard
logs under OUT/tensorboard,
  openmulti train --preset rl_lite --action-form team --critic central --reward-baseline never_always
    --episode-seeds 2 --scenes random:100 random:101 random:102 random:103 random:104 random:105 random:106
    random:107 --env-steps 1536 --seed 0 --out runs/learn/team_s0
and with links that come and go, the team's decision gates what instance_novelty picks (the shipped `learned`),
  ... --link-range-m 2.5 --action-form team --payload instance_novelty --read-links true --critic central
On a cluster: RLlib's PPO with one env runner per core (the same settings, run folder and policy files),
  openmulti train --backend rllib --ray auto --workers 32 --env-steps 200000 --out runs/train_cluster
(started on the cluster's head node, or `ray job submit --working-dir . -- openmulti train ...`;
docs/ray.md). --backend rllib alone runs its env runners on a Ray started on this machine."""


def _subparser(parser: argparse.ArgumentParser, command: str) -> argparse.ArgumentParser:
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]


def unknown_option_message(parser: argparse.ArgumentParser, command: str, unknown: list[str]) -> str:
    """What the command line gave that no option takes, and the nearest options."""
    import difflib  # noqa: PLC0415

    sub = _subparser(parser, command)
    given = next((u for u in unknown if u.startswith("-")), unknown[0]).split("=", 1)[0]
    near = difflib.get_close_matches(given, sorted(sub._option_string_actions), n=3, cutoff=0.6)
    return f"unknown option {given!r}" + (f"; did you mean {', '.join(near)}?" if near else
                                          f" (openmulti {command} --help lists them)")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script."""
    parser = build_parser()
    args, unknown = parser.parse_known_args(normalise_argv(sys.argv[1:] if argv is None else list(argv)))
    if unknown:
        print(f"openmulti {args.command}: error: {unknown_option_message(parser, args.command, unknown)}", file=sys.stderr)
        return 2
    try:
        return int(args.func(args))
    except ConfigError as exc:
        options = _subparser(parser, args.command)._option_string_actions
        print(f"openmulti {args.command}: error: {spelled_for_command_line(str(exc), options)}", file=sys.stderr)
        return 2
    except (ValueError, OSError, KeyError, TextEncoderError, ImageEncoderError) as exc:
        print(f"openmulti {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
