"""Whether the real-data path loses anything: one simulated room mapped through ``--scene`` and, exported in the
Replica layout, through ``--data``.

Issue: the same figures within noise; the noise yardstick is the same ``--data`` run with the next seed, which
changes only the network initialisation and the evaluation's point sampling. Also the geometric segmenter's
cost per frame and the TSDF reference's cost.

Run: `.venv/bin/python -m studies.real_data [--scene room0] [--agents 4] [--preset tiny]
[--out runs/bench_real_data]`. Both runs use perfect masks (the export writes the simulator's instance
images, so ``--data`` has no error model), alignment none, policy never, the same seed.

Figures: docs/real_data.md#measured
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import time
from pathlib import Path

import numpy as np
import torch

from mapping.data import load_dataset
from mapping.evaluate.reference import tsdf_reference_mesh
from mapping.perception.geometric_segmenter import GeometricSegmenter
from openmulti_env.runs.run import run_data
from mapping.pipeline.records import write_json_atomic
from openmulti_env.runs.run import run
from openmulti_env.experiment.presets import world_config
from openmulti_env.world import World
from openmulti_env.world.export import export_world
from openmulti_env.world.sensor import RGBDSensor, SensorConfig

KEYS = ("acc_cm", "comp_cm", "comp_ratio", "f_miou", "f_macc")


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def segmenter_cost(frames: list) -> tuple[float, float, int]:
    """Median and mean seconds per frame of the geometric segmenter on ``frames``, and the mean mask count."""
    seg = GeometricSegmenter()
    seg.segment(frames[0])  # open3d import and first-call set-up are not per-frame costs
    times, masks = [], []
    for f in frames:
        t0 = time.perf_counter()
        masks.append(len(seg.segment(f).segments))
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), float(np.mean(times)), int(np.mean(masks))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--scene", default="room0")
    parser.add_argument("--agents", type=int, default=4)
    parser.add_argument("--preset", default="tiny")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/bench_real_data")
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    root = Path(args.out) / f"{args.scene}_{args.preset}"
    shutil.rmtree(root, ignore_errors=True)
    data = root / "dataset"

    t0 = time.perf_counter()
    world = World.build(args.scene, seed=args.seed, config=world_config(args.preset, args.agents))
    export_world(world, data, "replica")
    world.close()
    sensor = RGBDSensor(world.scene, SensorConfig(), seed=args.seed)  # the default 320x240 camera
    poses = np.concatenate(world.agent_poses)
    full_frames = [sensor.render(poses[i], index=int(i)) for i in np.linspace(0, len(poses) - 1, 30).astype(int)]
    sensor.close()
    export_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    scene = run(args.scene, args.agents, "never", args.preset, args.seed, root / "scene", device="cpu",
                segmentation_errors=False)
    scene_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    real = run_data(data, args.agents, "never", args.preset, args.seed, root / "data", gt_mesh=str(data / "mesh.ply"),
                    device="cpu")
    data_s = time.perf_counter() - t0
    # the noise yardstick: the same data set mapped and sampled with the next seed
    other = run_data(data, args.agents, "never", args.preset, args.seed + 1, root / "data_seed2",
                     gt_mesh=str(data / "mesh.ply"), device="cpu")

    ds = load_dataset(data)
    small = segmenter_cost([ds[i] for i in np.linspace(0, len(ds) - 1, 30).astype(int)])
    full = segmenter_cost(full_frames)
    t0 = time.perf_counter()
    ref = tsdf_reference_mesh(ds)
    tsdf_s = time.perf_counter() - t0

    print(f"\nmachine: {platform.machine()}, {os.cpu_count()} cores (shared with other jobs), {args.threads} torch "
          f"threads, load average {os.getloadavg()[0]:.2f}")
    print(f"{args.scene}, {args.agents} agents, preset {args.preset}, seed {args.seed}, perfect masks, alignment none\n")
    print(f"| agent | path | {' | '.join(KEYS)} | instances |")
    print("|---|---|" + "---|" * (len(KEYS) + 1))
    for name in list(scene["agents"]) + ["mean"]:
        for label, res in (("--scene", scene), ("--data", real)):
            m = res["mean"] if name == "mean" else res["agents"][name]
            print(f"| {name} | {label} | {' | '.join(_fmt(m[k]) for k in KEYS)} | {m.get('instances', '')} |")
    diff = {k: None if scene["mean"][k] is None or real["mean"][k] is None else real["mean"][k] - scene["mean"][k]
            for k in KEYS}
    noise = {k: None if real["mean"][k] is None or other["mean"][k] is None else other["mean"][k] - real["mean"][k]
             for k in KEYS}
    print(f"\nmean difference (--data minus --scene): {', '.join(f'{k} {_fmt(v)}' for k, v in diff.items())}")
    print(f"noise (--data, seed {args.seed + 1} minus seed {args.seed}): "
          f"{', '.join(f'{k} {_fmt(v)}' for k, v in noise.items())}")
    print(f"team F-mIoU: --scene {_fmt(scene['team']['f_miou'])}, --data {_fmt(real['team']['f_miou'])}")
    k = ds.intrinsics
    print(f"wall: export {export_s:.0f} s, --scene {scene_s:.0f} s, --data {data_s:.0f} s")
    for (w, h), (median_s, mean_s, masks) in (((k.width, k.height), small), ((320, 240), full)):
        print(f"geometric segmenter at {w}x{h}: median {1000 * median_s:.0f} ms/frame (mean {1000 * mean_s:.0f}), "
              f"{masks} masks per frame on average")
    print(f"TSDF reference (1 cm voxels) of all {len(ds)} frames: {tsdf_s:.1f} s, {len(ref.faces)} faces")
    write_json_atomic(root / "bench.json", {
        "scene": scene["mean"], "data": real["mean"], "difference": diff, "noise": noise,
        "team_f_miou": {"scene": scene["team"]["f_miou"], "data": real["team"]["f_miou"]},
        "wall_s": {"export": export_s, "scene": scene_s, "data": data_s, "tsdf_reference": tsdf_s},
        "segmenter_s_per_frame": {f"{k.width}x{k.height}": small[:2], "320x240": full[:2]},
        "load_average": os.getloadavg()[0]})


if __name__ == "__main__":
    main()
