"""Eq. 12 and eq. 13 variants: where does each put or take the team's surface?

Run: `.venv/bin/python -m studies.cross_rendering [--scene room0] [--preset demo] [--variants ...]`.

Every variant is the `openmulti` team (policy `always`) with other eq. 12 / eq. 13 settings
(`ConsistencyConfig` fields, written out where they differ from today's defaults). After the last round each agent's map is probed on 20k ground-truth
surface samples (`mapping.evaluate.probe`, no meshing: a run costs its rounds only) and the coverage is
split by whether the agent's own frames observed the sample ("seen") or not ("blind": what the team
must give it). A finished variant whose row holds the same settings is not run again (delete
`--out/<name>.json` to redo it); results are written atomically. Prints a Markdown table and writes `--out/bench_cross_rendering.json` and `.png`.

Figures: docs/learner.md#the-eq-12--eq-13-study
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

EQ12_AFTER_EXCHANGE = {"local_consensus": False, "rho": 0.3}
"""Eq. 12 as it was before 2026-12-02: consensus at rho 0.3 in the consistency iterations only."""

VARIANTS: dict[str, dict] = {
    # eq. 13's forms and targets, with eq. 12 in the consistency iterations only (2026-12-01)
    "no_cross": {**EQ12_AFTER_EXCHANGE, "cross_rendering": False},
    "paper_current_w1": {**EQ12_AFTER_EXCHANGE, "cross_rendering_form": "composite", "ray_poses": "current",
                         "render_weight": 1.0},
    "current_w1_blind": {**EQ12_AFTER_EXCHANGE, "cross_rendering_form": "composite", "ray_poses": "current",
                         "render_weight": 1.0, "blind_zones_only": True},
    "mapped_w1": {**EQ12_AFTER_EXCHANGE, "ray_poses": "mapped", "render_weight": 1.0},
    "mapped_w1_blind": {**EQ12_AFTER_EXCHANGE, "ray_poses": "mapped", "render_weight": 1.0, "blind_zones_only": True},
    "mapped_w0.3": {**EQ12_AFTER_EXCHANGE},
    "mapped_w0.1": {**EQ12_AFTER_EXCHANGE, "ray_poses": "mapped", "render_weight": 0.1},
    "mapped_w0.3_rho3": {**EQ12_AFTER_EXCHANGE, "rho": 3.0},
    "rays_1024": {**EQ12_AFTER_EXCHANGE, "rays_per_pose": 1024},
    "instance_mapped_w1_blind": {**EQ12_AFTER_EXCHANGE, "cross_rendering_form": "instance", "ray_poses": "mapped",
                                 "render_weight": 1.0, "blind_zones_only": True},
    "dsgd": {"algorithm": "dsgd"},
    # eq. 12 in every local iteration too (2026-12-02)
    "local_consensus_rho0.3": {"rho": 0.3},
    "local_consensus_rho0.3_no_cross": {"rho": 0.3, "cross_rendering": False},
    "default": {},
    "default_no_cross": {"cross_rendering": False},
}
"""Name -> ConsistencyConfig overrides (``default``: the library's defaults)."""


def run_key(overrides: dict, scene: str, preset: str, seed: int) -> dict:
    """What decides a variant's row: scene, preset, seed and every team setting it learns with
    (the variant's ConsistencyConfig in full, the library's message and mapper defaults), so that a
    changed default or another scene redoes the row instead of reusing it."""
    from dataclasses import asdict

    from mapping.team import ConsistencyConfig
    from openmulti_env.runs.reproduce.runner import library_defaults
    from mapping.pipeline.records import as_record

    defaults = library_defaults(preset)
    return {"scene": scene, "preset": preset, "seed": seed,
            "consistency": as_record(asdict(ConsistencyConfig(**overrides))),
            "exchange": defaults["exchange"], "mapping": defaults["mapping"]}


def seen_by_own_frames(world, agent: int, points: np.ndarray, stride: int = 5, tolerance_m: float = 0.03) -> np.ndarray:
    """(P,) bool: some frame of the agent's path (every ``stride``-th) shows the point at its depth."""
    k, seen = world.intrinsics, np.zeros(len(points), bool)
    for i in range(0, len(world.agent_poses[agent]), stride):
        w2c = np.linalg.inv(np.asarray(world.agent_poses[agent][i], np.float64))
        cam = points @ w2c[:3, :3].T + w2c[:3, 3]
        z = cam[:, 2]
        front = z > 0.05
        zs = np.where(front, z, 1.0)
        u = np.round(k.fx * cam[:, 0] / zs + k.cx).astype(int)
        v = np.round(k.fy * cam[:, 1] / zs + k.cy).astype(int)
        inside = front & (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
        depth = world.render(agent, i).depth
        observed = np.zeros(len(points))
        observed[inside] = depth[v[inside], u[inside]]
        seen |= inside & (np.abs(observed - z) < tolerance_m)
    return seen


def run_variant(name: str, overrides: dict, scene: str, preset: str, seed: int, threads: int) -> dict:
    from mapping.evaluate.probe import surface_probe_coverage
    from mapping.perception import shared_text_encoder
    from mapping.runtime import set_threads
    from mapping.team import ChannelConfig, RoundPlan, Team
    from openmulti_env.experiment.presets import mapping_config, team_config, world_config
    from openmulti_env.world.stream import world_streams, world_vocabulary
    from openmulti_env.world import World
    from tqdm import tqdm

    set_threads(threads)
    world = World.build(scene, seed=seed, config=world_config(preset, 4))
    encoder = shared_text_encoder()
    config = team_config(preset, mapping=mapping_config(preset), consistency=overrides)
    team = Team(world_streams(world, seed, True, text_encoder=encoder), config, world_vocabulary(world, encoder),
                seed=seed, channel=ChannelConfig(1.0, None), device="cpu")
    start = time.perf_counter()
    for _ in tqdm(range(team.rounds_total()), desc=name, unit="round"):
        team.round(RoundPlan.always(team.num_agents))
    rounds_s = time.perf_counter() - start
    points, normals, _ = world.surface.sample_points(20000, seed=seed)
    agents = []
    for a, member in enumerate(team.members):
        covered = surface_probe_coverage(member.mapper, points, normals)
        seen = seen_by_own_frames(world, a, points)
        agents.append({"coverage": float(covered.mean()), "seen": float(covered[seen].mean()),
                       "blind": float(covered[~seen].mean()), "seen_share": float(seen.mean())})
    world.close()
    mean = {key: float(np.mean([x[key] for x in agents])) for key in agents[0]}
    return {"variant": name, "overrides": overrides, "key": run_key(overrides, scene, preset, seed), "scene": scene,
            "preset": preset, "seed": seed,
            "rounds_s": rounds_s, "threads": threads, "agents": agents, "mean": mean}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="room0")
    parser.add_argument("--preset", default="demo")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), help=f"known: {', '.join(VARIANTS)}")
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--out", type=Path, default=Path("runs/bench_cross_rendering"))
    args = parser.parse_args()
    unknown = [v for v in args.variants if v not in VARIANTS]
    if unknown:
        parser.error(f"unknown variants {unknown}; known: {', '.join(VARIANTS)}")
    from mapping.pipeline.records import write_json_atomic

    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.variants:
        path = args.out / f"{name}.json"
        if path.is_file():
            row = json.loads(path.read_text())
            if row.get("key") == run_key(VARIANTS[name], args.scene, args.preset, args.seed):
                rows.append(row)
                continue
        row = run_variant(name, VARIANTS[name], args.scene, args.preset, args.seed, args.threads)
        write_json_atomic(path, row)
        rows.append(row)
    print(f"\n{args.scene}, preset {args.preset}, seed {args.seed}, 4 agents, policy always; "
          f"{platform.machine()} CPU, {os.cpu_count()} cores\n")
    print("| variant | coverage [%] | seen [%] | blind [%] | rounds [s] |")
    print("|---|---|---|---|---|")
    for r in rows:
        m = r["mean"]
        print(f"| `{r['variant']}` | {100 * m['coverage']:.1f} | {100 * m['seen']:.1f} | {100 * m['blind']:.1f} | "
              f"{r['rounds_s']:.0f} |")
    write_json_atomic(args.out / "bench_cross_rendering.json", {"rows": rows})
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(11, 4.2))
    x = np.arange(len(rows))
    for k, (key, label) in enumerate((("coverage", "whole room"), ("seen", "seen by the agent"),
                                      ("blind", "blind zones"))):
        ax.bar(x + (k - 1) * 0.27, [100 * r["mean"][key] for r in rows], 0.27, label=label)
    ax.set_xticks(x, [r["variant"] for r in rows], rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("probe coverage [%]")
    ax.set_ylim(0, 100)
    ax.set_title(f"eq. 12 / eq. 13 variants, {args.scene} {args.preset} seed {args.seed}: mean of 4 agents")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(args.out / "bench_cross_rendering.png", dpi=120)
    print(f"\nwrote {args.out / 'bench_cross_rendering.json'} and .png")


if __name__ == "__main__":
    main()
