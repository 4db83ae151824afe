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

from mapping.perception.geometric_segmenter import SEGMENTER_SETTINGS
from mapping.perception.image_encoder import ImageEncoderError
from mapping.perception.text_encoder import TextEncoderError
from mapping.team.consistency import MISSING_EDGES
from policies.scripted import parse_policy

RUN_PRESETS = ("tiny", "demo", "fast", "full", "rl_tiny", "rl_small", "rl")  # openmulti_env.presets.PRESET_NAMES (a test checks)
MAX_AGENTS = 8  # openmulti_env.world.world.MAX_AGENTS (a test checks they agree)

def check_policy(name: str) -> str:
    """Validate a policy name (``policies.POLICY_FORMS``): PolicyError naming the problem."""
    return parse_policy(name).name


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
    from openmulti_env.presets import world_config  # noqa: PLC0415
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
    from openmulti_env.runs.run import run, run_data  # noqa: PLC0415

    policy = check_policy(args.policy)
    out = Path(args.out)
    team_options = dict(device=args.device, alignment=args.alignment, clip_checkpoint=args.clip_checkpoint,
                        comm_budget_mb=args.comm_budget_mb, consistency=args.consistency,
                        missing_edges=args.missing_edges, cross_rendering=args.cross_rendering,
                        float16=args.float16, changed_only=args.changed_only, threads=args.threads,
                        workers=args.workers, processes=args.processes, holdout_every=args.holdout_every,
                        learner=args.learner, evaluate=not args.no_evaluation)
    what = f"scene {args.scene}" if args.data is None else f"data {args.data}"
    print(f"[openmulti] {what}, {args.agents} agents, preset {args.preset}, seed {args.seed}, "
          f"policy {policy}, alignment {args.alignment}, consistency {args.consistency}"
          f"{'' if args.cross_rendering else ', no cross rendering'}")
    if args.data is None:
        if args.segmenter != "fixed":
            raise ValueError("--segmenter is for --data without instance images; the simulator's masks come from "
                             "its own error model (--perfect-masks turns it off)")
        metrics = run(args.scene, args.agents, policy, args.preset, args.seed, out,
                      segmentation_errors=not args.perfect_masks, **team_options)
    else:
        if args.perfect_masks:
            raise ValueError("--perfect-masks is for --scene (the simulator's error model); with --data the masks "
                             "are the data set's instance images or the geometric segmenter's")
        metrics = run_data(args.data, args.agents, policy, args.preset, args.seed, out, kind=args.kind,
                           gt_mesh=args.gt_mesh, frames=args.frames, intrinsics=args.intrinsics,
                           depth_scale=args.depth_scale, segmenter=args.segmenter, **team_options)
    fields = set(RunResult.__dataclass_fields__) - {"extra"}
    result = RunResult(**{k: v for k, v in metrics.items() if k in fields},
                       extra={k: v for k, v in metrics.items() if k not in fields})
    print()
    print("\n".join(results_table(result, out)))
    return 0


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
    p.add_argument("--preset", choices=RUN_PRESETS, default="fast", help="episode size (frames, image size)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--render", metavar="DIR", help="write a top-down picture and a few frames per agent")
    p.add_argument("--export", metavar="DIR", help="write the world as an RGB-D data set (frames of all agents)")
    p.add_argument("--layout", choices=("replica", "scannet", "nice_slam"), default="replica",
                   help="data set layout of --export")
    p.set_defaults(func=cmd_scenes)

    p = sub.add_parser("run", help="a multi-agent team run on one scene (--scene) or a real RGB-D data set (--data)",
                       formatter_class=fmt)
    p.add_argument("--scene", default="room0", help="scene preset (openmulti scenes lists them), random:SEED, or "
                   "the path of a JSON/YAML manifest of your own meshes")
    p.add_argument("--agents", type=_agents, default=4, help="agents in the team (each maps its own region)")
    p.add_argument("--policy", default="always", help="communication policy: always, never, round_robin, budget "
                   "(with --comm-budget-mb), every:K (everything every K-th round), at:R1,R2,... (everything on the listed "
                   "rounds), rate:Q (each link with "
                   "probability Q), bernoulli:P (always; each message arrives with probability P), novelty[:k=v,...] "
                   "(reads the observations: policies/novelty.py), learned (the trained policy shipped with the "
                   "package) or a trained policy file (.json beside its .safetensors)")
    p.add_argument("--preset", choices=RUN_PRESETS, default="fast",
                   help="episode size: tiny (smoke), demo (make demo), fast, full (the paper's), rl_tiny, rl_small, rl "
                        "(the env's RL-sized ones)")
    p.add_argument("--seed", type=int, default=0, help="one seed for layout, paths, segmentation errors, channel "
                   "draws and network initialisation")
    p.add_argument("--out", default="runs/demo", help="output folder (the same folder and settings resume a run)")
    p.add_argument("--device", default="auto", help="cpu, cuda or auto (cuda when available)")
    p.add_argument("--alignment", choices=("paper", "none"), default="paper",
                   help="align arrived instances (paper, sec. III-C) or adopt each as a new one (none)")
    p.add_argument("--consistency", choices=("consensus", "dinno", "dsgd", "none"), default="consensus",
                   help="parameter consistency, eq. 12 (consensus = MACIM's)")
    p.add_argument("--missing-edges", choices=MISSING_EDGES, default="skip",
                   help="DiNNO and DSGD with a peer whose vector did not arrive this round: skip the edge (default) "
                        "or use the last vector held (the stale form)")
    p.add_argument("--no-cross-rendering", dest="cross_rendering", action="store_false",
                   help="no render consistency on shared rays (eq. 13): the ablation")
    p.add_argument("--comm-budget-mb", type=float, metavar="MB", help="bytes each agent may send over the run")
    p.add_argument("--float16", action="store_true", help="send network vectors as float16")
    p.add_argument("--changed-only", type=float, metavar="REL",
                   help="skip instances whose parameters moved less than REL (relative L2) since last sent")
    p.add_argument("--threads", type=int, help="torch threads (default: all cores, shared by the workers)")
    p.add_argument("--workers", type=int,
                   help="agents trained side by side on threads (default: one per core, 1 torch thread each; "
                        "1 when --threads is given); results do not depend on it")
    p.add_argument("--holdout-every", type=int, metavar="K",
                   help="keep every K-th frame of each agent out of its map and report the map's depth error on "
                        "those unseen views too (depth_heldout_* in metrics.json); K >= 2")
    p.add_argument("--processes", choices=("ray",),
                   help="ray: every agent maps in a process of its own (a Ray actor, here or on the cluster of "
                        "RAY_ADDRESS), exchanging only serialised messages; the same maps on CPU. Needs "
                        "pip install 'openmulti[ray]'")
    p.add_argument("--learner", choices=("per_agent", "fleet"), default="per_agent",
                   help="fleet: every agent's training steps batched into one computation per step (one large "
                        "kernel on a GPU; pair with --threads on a CPU); the same maps to float tolerance")
    p.add_argument("--no-evaluation", action="store_true",
                   help="map only: rounds, bytes and the final checkpoint, no meshes or scores; the same command "
                        "without it resumes after the last round and scores the maps")
    p.add_argument("--clip-checkpoint", metavar="PATH",
                   help="local open_clip checkpoint: masks get visual features (optional extra openmulti[clip])")
    p.add_argument("--perfect-masks", action="store_true",
                   help="segment without the front end's error model (no semantic / over- / under-segmentation errors)")
    g = p.add_argument_group("real RGB-D data (instead of --scene; the team and the options above run on it, "
                             "--perfect-masks aside: the masks are the data set's or the geometric segmenter's)")
    g.add_argument("--data", metavar="DIR", help="a data set folder: Replica (vMAP or NICE-SLAM layout) or ScanNet, "
                   "cut into --agents contiguous sequences")
    g.add_argument("--kind", choices=("auto", "replica", "nice_slam", "scannet"), default="auto",
                   help="data set layout (auto: detected from the folder)")
    g.add_argument("--gt-mesh", metavar="PLY", help="ground-truth mesh (else a TSDF reference of the frames)")
    g.add_argument("--frames", metavar="A:B:S", help="frames A..B-1 every S-th, before the split into agents")
    g.add_argument("--intrinsics", metavar="FX,FY,CX,CY", help="override the data set's camera")
    g.add_argument("--depth-scale", type=float, metavar="UNITS", help="raw depth units per metre (Replica 1000 "
                   "vMAP / 6553.5 NICE-SLAM, ScanNet 1000; default: the layout's or cam_params.json)")
    g.add_argument("--segmenter", choices=tuple(SEGMENTER_SETTINGS), default="fixed",
                   help="the geometric segmenter's thresholds, for data without instance images: fixed, or "
                   "range_aware (planes and clusters widen with a structured-light sensor's noise at depth; better "
                   "on recordings within about 3 m, worse beyond: docs/real_data.md)")
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
                   "transmission, all (the paper's six), or tradeoff (completion against MB of every scripted "
                   "policy and the learned one)")
    p.add_argument("--scenes", nargs="+", metavar="S", help="scenes of the grid (default: room0; tradeoff: room0 "
                   "office0 room2)")
    p.add_argument("--seeds", nargs="+", type=int, default=[0], metavar="K", help="seeds of the grid")
    p.add_argument("--preset", choices=RUN_PRESETS, default="fast", help="episode size of every run")
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
                   help="run only these of the table's methods (tradeoff: these policies)")
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
                       formatter_class=_RawDefaults, description=TRAIN_HELP)
    p.add_argument("--out", default="runs/train", help="folder of the run: checkpoint (resumed), log.csv, "
                   "learning_curve.png, best.json/.safetensors and latest.json/.safetensors")
    p.add_argument("--preset", choices=RUN_PRESETS, default="rl_small", help="episode size of the env")
    p.add_argument("--agents", type=_agents, default=4, help="team size (a policy runs on teams of this size)")
    p.add_argument("--scenes", nargs="+", metavar="SCENE", help="training worlds (default: random:100 .. random:115; "
                   "room0, office0 and room2 are held out for the trade-off table)")
    p.add_argument("--episodes-per-world", type=int, default=2, help="episodes before a worker moves to its next world")
    p.add_argument("--env-steps", type=int, default=20000, help="env steps (team rounds) over all workers")
    p.add_argument("--workers", type=int, default=2, help="worker processes, each stepping its own env (RLlib: env "
                   "runners)")
    p.add_argument("--backend", choices=("sb3", "rllib"), default="sb3",
                   help="sb3: Stable-Baselines3 PPO in worker processes here; rllib: RLlib's multi-agent PPO, its env "
                        "runners on a local Ray or on --ray ADDRESS (pip install 'openmulti[ray]')")
    p.add_argument("--ray", metavar="ADDRESS", help="with --backend rllib: the Ray cluster's address (ray://HOST:10001, "
                   "HOST:6379 or auto; default: a Ray started on this machine)")
    p.add_argument("--reward", choices=("team", "individual"), default="team")
    p.add_argument("--comm-cost-per-mb", type=float, default=0.0025, help="reward cost per megabyte sent (the team's "
                   "MB over the team size)")
    p.add_argument("--comm-budget-mb", type=float, metavar="MB", help="megabytes each agent may send per episode")
    p.add_argument("--horizon", type=int, help="steps per episode (default: until the paths end)")
    p.add_argument("--action-form", choices=("entries", "round"), default="entries",
                   help="entries: a send decision per peer and half (parameters, rays); round: one per agent and "
                   "round, everything to every peer or nothing (sb3 backend)")
    p.add_argument("--n-steps", type=int, default=32, help="PPO: rounds per worker and agent between updates")
    p.add_argument("--batch-size", type=int, default=64, help="PPO minibatch")
    p.add_argument("--learning-rate", type=float, default=3e-4, help="PPO learning rate")
    p.add_argument("--ent-coef", type=float, default=0.01, help="PPO entropy bonus")
    p.add_argument("--chunk-env-steps", type=int, default=512, help="checkpoint, policy files and log every this many "
                   "env steps")
    p.add_argument("--seed", type=int, default=0)
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
On a cluster: RLlib's PPO with one env runner per core (the same settings, run folder and policy files),
  openmulti train --backend rllib --ray auto --workers 32 --env-steps 200000 --out runs/train_cluster
(started on the cluster's head node, or `ray job submit --working-dir . -- openmulti train ...`;
docs/ray.md). --backend rllib alone runs its env runners on a Ray started on this machine."""


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except (ValueError, FileNotFoundError, KeyError, TextEncoderError, ImageEncoderError) as exc:
        print(f"openmulti {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
