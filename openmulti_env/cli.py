"""The ``openmulti`` command line: ``scenes``, ``run`` (``--policy never`` maps every agent alone, after the
open-vocabulary front end and optional cross-agent alignment) and ``query``; ``reproduce`` and ``train``
arrive with the multi-agent exchange and the env."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from openmulti_env.results import write_json_atomic
from mapping.perception.image_encoder import ImageEncoderError
from mapping.perception.text_encoder import TextEncoderError
from openmulti_env.team_perception import ALIGNMENT_MODES
from openmulti_env.run_presets import RUN_PRESETS, world_config
from openmulti_env.world import World, list_presets, make_scene
from openmulti_env.world.presets import PRESETS
from openmulti_env.world.world import MAX_AGENTS

SCRIPTED_POLICIES = ("always", "never", "round_robin", "budget")
PENDING = {
    "reproduce": "the paper's tables need the mapper (#3) and the multi-agent optimisation",
    "train": "training communication schedules needs the PettingZoo env",
}


def check_policy(name: str) -> str:
    """Validate a policy name: always, never, round_robin, budget, bernoulli:P, or a file path."""
    if name in SCRIPTED_POLICIES:
        return name
    if name.startswith("bernoulli:"):
        try:
            p = float(name.split(":", 1)[1])
        except ValueError:
            p = -1.0
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"policy {name!r}: bernoulli:P needs a success probability P in [0, 1]")
        return name
    if Path(name).is_file():
        return name
    raise ValueError(f"unknown policy {name!r}: use {', '.join(SCRIPTED_POLICIES)}, bernoulli:P or a trained policy file")


def _agents(value: str) -> int:
    n = int(value)
    if not 1 <= n <= MAX_AGENTS:
        raise argparse.ArgumentTypeError(f"--agents must be between 1 and {MAX_AGENTS}, got {n}")
    return n


def cmd_scenes(args: argparse.Namespace) -> int:
    """List presets, or describe one scene with its coverage (and optionally render pictures)."""
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
    """The main job: with policy ``never`` every agent maps alone and metrics.json is written; other
    policies need the multi-agent exchange (not built yet), so only the world part runs for them."""
    policy = check_policy(args.policy)
    out = Path(args.out)
    if args.data is not None:
        return _run_data(args, policy, out)
    if policy == "never":
        return _run_mapping(args, out)
    start = time.perf_counter()
    print(f"[openmulti] scene {args.scene}, {args.agents} agents, preset {args.preset}, seed {args.seed}, policy {policy}")
    t0 = time.perf_counter()
    world = World.build(args.scene, seed=args.seed, config=world_config(args.preset, args.agents))
    print(f"[openmulti] world built in {time.perf_counter() - t0:.1f} s: {len(world.scene.instances)} instances, "
          f"{world.surface.visible_fraction:.0%} of the surface observable")
    samples = {}
    total = sum(len(p) for p in world.agent_poses)
    with tqdm(total=total, desc="rendering frames", unit="frame") as bar:
        for a, poses in enumerate(world.agent_poses):
            keep = set(np.linspace(0, len(poses) - 1, 3).astype(int).tolist())
            for i in range(len(poses)):
                frame = world.render(a, i)
                if i in keep:
                    samples.setdefault(a, []).append(frame)
                bar.update(1)
    report = world.coverage()

    from openmulti_env.world.plots import save_frames, save_world_overview  # noqa: PLC0415

    (out / "meshes").mkdir(parents=True, exist_ok=True)
    world.scene.mesh().export(out / "meshes" / "gt_scene.ply")
    world.surface.culled_mesh().export(out / "meshes" / "gt_observable.ply")
    gt, _, _ = world.surface.sample_points(20000, seed=args.seed)
    save_world_overview(out / "plots" / "top_down.png", world.scene, world.agent_poses, gt, world.caster,
                        world.intrinsics)
    for a, frames in samples.items():
        save_frames(out / "plots" / f"frames_agent_{a}.png", frames, f"{world.scene.name} agent_{a}")
    cov = report.as_dict()
    write_json_atomic(out / "world.json", {
        "scene": world.scene.describe(), "agents": args.agents, "preset": args.preset, "seed": args.seed,
        "policy": policy, "frames_rendered": total, "coverage": cov, "wall_s": time.perf_counter() - start,
        "stages_run": ["scene", "culling", "paths", "rendering", "coverage"],
    })
    print()
    print(f"{'agent':<10} {'frames':>6} {'coverage %':>10}")
    for a, poses in enumerate(world.agent_poses):
        print(f"agent_{a:<4} {len(poses):>6} {cov['per_agent_pct'][a]:>10.1f}")
    print(f"{'team':<10} {total:>6} {cov['union_pct']:>10.1f}")
    print()
    print("Ran: scene, observable ground truth, agent paths, RGB-D + instance rendering, coverage.")
    print(f"Not run: mapping. Policy {policy!r} needs the multi-agent exchange of parameters and rays, which is"
          " not built yet, so no metrics.json was written; --policy never maps every agent alone.")
    print(f"Wrote {out}/world.json, {out}/meshes/, {out}/plots/ in {time.perf_counter() - start:.1f} s")
    world.close()
    return 0


def _run_mapping(args: argparse.Namespace, out: Path) -> int:
    from openmulti_env.run import run  # noqa: PLC0415

    print(f"[openmulti] scene {args.scene}, {args.agents} agents, preset {args.preset}, seed {args.seed}, "
          f"policy never (each agent maps alone)")
    result = run(args.scene, args.agents, "never", args.preset, args.seed, out, device=args.device,
                 alignment=args.alignment, segmentation_errors=not args.perfect_masks,
                 clip_checkpoint=args.clip_checkpoint)
    print()
    print(f"{'agent':<10} {'acc [cm]':>9} {'comp [cm]':>10} {'comp ratio [%]':>15} {'F-mIoU':>7} {'F-mAcc':>7} "
          f"{'instances':>10}")
    for name, m in result["agents"].items():
        print(f"{name:<10} {_fmt(m['acc_cm']):>9} {_fmt(m['comp_cm']):>10} {_fmt(m['comp_ratio']):>15} "
              f"{_fmt(m['f_miou']):>7} {_fmt(m['f_macc']):>7} {m['instances']:>10}")
    mean, team = result["mean"], result["team"]
    print(f"{'mean':<10} {_fmt(mean['acc_cm']):>9} {_fmt(mean['comp_cm']):>10} {_fmt(mean['comp_ratio']):>15} "
          f"{_fmt(mean['f_miou']):>7} {_fmt(mean['f_macc']):>7}")
    print(f"{'team map':<10} {'':>9} {'':>10} {'':>15} {_fmt(team['f_miou']):>7} {_fmt(team['f_macc']):>7} "
          f"{team['global_instances']:>10}")
    print(f"\nalignment {args.alignment}: {result['bytes_sent_total'] / 1e6:.2f} MB of point clouds exchanged")
    print(f"Wrote {out}/metrics.json, {out}/meshes/, {out}/codebook/, {out}/plots/ in {result['wall_s']:.1f} s; "
          f'try: openmulti query --run {out} "somewhere to sit"')
    return 0


def _run_data(args: argparse.Namespace, policy: str, out: Path) -> int:
    from openmulti_env.data_run import run_data, summary_lines  # noqa: PLC0415

    print(f"[openmulti] data {args.data}, {args.agents} agents, preset {args.preset}, seed {args.seed}, policy {policy}")
    result = run_data(args.data, args.agents, policy, args.preset, args.seed, out, kind=args.kind,
                      gt_mesh=args.gt_mesh, frames=args.frames, intrinsics=args.intrinsics,
                      depth_scale=args.depth_scale, device=args.device, alignment=args.alignment,
                      clip_checkpoint=args.clip_checkpoint)
    print()
    print("\n".join(summary_lines(result)))
    print(f"Wrote {out}/metrics.json, {out}/meshes/, {out}/codebook/, {out}/plots/ in {result['wall_s']:.1f} s; "
          f'try: openmulti query --run {out} "the table"')
    return 0


def cmd_query(args: argparse.Namespace) -> int:
    """Rank a run's instances against a text query; print JSON and write DIR/plots/query_<slug>.png."""
    from openmulti_env.query import run_query  # noqa: PLC0415

    result = run_query(args.run, args.text, top_k=args.top, clip_checkpoint=args.clip_checkpoint)
    print(json.dumps(result.payload, indent=2))
    return 0


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of the ``openmulti`` command."""
    parser = argparse.ArgumentParser(prog="openmulti", description="OpenMulti multi-agent implicit mapping")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("scenes", help="list presets, or describe one scene and its coverage")
    p.add_argument("scene", nargs="?", help="preset name, random:SEED or manifest path")
    p.add_argument("--agents", type=_agents, default=4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--preset", choices=RUN_PRESETS, default="fast")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--render", metavar="DIR", help="write a top-down picture and a few frames per agent")
    p.add_argument("--export", metavar="DIR", help="write the world as an RGB-D data set (frames of all agents)")
    p.add_argument("--layout", choices=("replica", "scannet", "nice_slam"), default="replica",
                   help="data set layout of --export")
    p.set_defaults(func=cmd_scenes)

    p = sub.add_parser("run", help="a multi-agent run on one scene")
    p.add_argument("--scene", default="room0")
    p.add_argument("--agents", type=_agents, default=4)
    p.add_argument("--policy", default="always")
    p.add_argument("--preset", choices=RUN_PRESETS, default="fast")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="runs/demo")
    p.add_argument("--device", default="auto", help="cpu, cuda or auto (cuda when available)")
    p.add_argument("--alignment", choices=ALIGNMENT_MODES, default="none",
                   help="cross-agent instance alignment before mapping: none (each agent alone), paper "
                        "(agents exchange instance point clouds once, sec. III-C) or oracle (ground-truth ids)")
    p.add_argument("--clip-checkpoint", metavar="PATH",
                   help="local open_clip checkpoint: masks get visual features (optional extra openmulti[clip])")
    p.add_argument("--perfect-masks", action="store_true",
                   help="segment without the front end's error model (no semantic / over- / under-segmentation errors)")
    g = p.add_argument_group("real RGB-D data (instead of --scene; --policy never only for now)")
    g.add_argument("--data", metavar="DIR", help="a data set folder: Replica (vMAP or NICE-SLAM layout) or ScanNet")
    g.add_argument("--kind", choices=("auto", "replica", "nice_slam", "scannet"), default="auto")
    g.add_argument("--gt-mesh", metavar="PLY", help="ground-truth mesh (else a TSDF reference of the frames)")
    g.add_argument("--frames", metavar="A:B:S", help="frames A..B-1 every S-th, before the split into agents")
    g.add_argument("--intrinsics", metavar="FX,FY,CX,CY", help="override the data set's camera")
    g.add_argument("--depth-scale", type=float, metavar="UNITS", help="raw depth units per metre (Replica 1000 "
                   "vMAP / 6553.5 NICE-SLAM, ScanNet 1000; default: the layout's or cam_params.json)")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("query", help="open-vocabulary instance retrieval on a finished run")
    p.add_argument("text", metavar="TEXT", help='what to look for, e.g. "somewhere to sleep"')
    p.add_argument("--run", required=True, metavar="DIR", help="run directory (with codebook/ and meshes/)")
    p.add_argument("--top", type=int, default=5, metavar="K", help="how many instances to print")
    p.add_argument("--clip-checkpoint", metavar="PATH", help="local image-text (CLIP) checkpoint: adds the visual term")
    p.set_defaults(func=cmd_query)

    for name, why in PENDING.items():
        p = sub.add_parser(name, help=f"(not available yet: {why})")
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(func=lambda a, why=why, name=name: _pending(name, why))
    return parser


def _pending(name: str, why: str) -> int:
    print(f"openmulti {name}: not available yet: {why}.", file=sys.stderr)
    return 2


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
