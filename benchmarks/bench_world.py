"""World benchmark: scene build time, culling + path planning time, coverage per preset, render speed.

Run: `.venv/bin/python benchmarks/bench_world.py [--presets room0 office0 ...] [--out runs/bench_world.json]`.
Prints tables; writes the figures as JSON (atomically) for the README.

Figures: docs/world.md#measured
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from openmulti_env.world import REPLICA_LIKE_PRESETS, World, WorldConfig, make_scene
from openmulti_env.world.sensor import RGBDSensor, SensorConfig


def bench_render(scene, poses, width: int, height: int, repeats: int = 60) -> float:
    """Frames per second of RGB + depth + instance rendering at ``width`` x ``height``."""
    sensor = RGBDSensor(scene, SensorConfig(width=width, height=height))
    sensor.render(poses[0])  # warm-up: GL context and buffers
    start = time.perf_counter()
    for i in range(repeats):
        sensor.render(poses[i % len(poses)])
    fps = repeats / (time.perf_counter() - start)
    sensor.close()
    return fps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--presets", nargs="*", default=list(REPLICA_LIKE_PRESETS))
    parser.add_argument("--agents", type=int, default=4)
    parser.add_argument("--out", default="runs/bench_world.json")
    args = parser.parse_args()

    rows = []
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores")
    print(f"{'preset':<9} {'inst':>4} {'scene_s':>7} {'world_s':>7} {'cover_s':>7} {'union%':>6}  per-agent %")
    for name in args.presets:
        t0 = time.perf_counter()
        scene = make_scene(name)
        t1 = time.perf_counter()
        world = World.build(scene, seed=0, config=WorldConfig(num_agents=args.agents))
        t2 = time.perf_counter()
        report = world.coverage()
        t3 = time.perf_counter()
        row = {"preset": name, "instances": len(scene.instances), "scene_build_s": t1 - t0,
               "world_build_s": t2 - t1, "coverage_s": t3 - t2, **report.as_dict()}
        rows.append(row)
        print(f"{name:<9} {len(scene.instances):>4} {t1 - t0:>7.2f} {t2 - t1:>7.2f} {t3 - t2:>7.2f} "
              f"{row['union_pct']:>6.1f}  {row['per_agent_pct']}")

    scene = make_scene(args.presets[0])
    world = World.build(scene, seed=0, config=WorldConfig(num_agents=args.agents))
    poses = np.concatenate(world.agent_poses)
    render = {f"{w}x{h}": bench_render(scene, poses, w, h) for w, h in ((320, 240), (640, 480))}
    for res, fps in render.items():
        print(f"render {res}: {fps:.1f} frames/s (RGB + depth + instance ids, {args.presets[0]})")

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps({"presets": rows, "render_fps": render, "cores": os.cpu_count()}, indent=2))
    os.replace(tmp, out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
