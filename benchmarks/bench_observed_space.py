"""Observed space per instance (issue 44): its bytes on the wire against the instance's network, and the
time to mark one keyframe, on a simulated room.

One agent's keyframes (every ``keyframe_every``-th frame of its path at the preset), each instance's box
from its mask's points, free rays from every ``--stride``-th valid pixel and a quarter of the instance's own
pixels. Target: a grid at most 5 % of the parameter bytes.

    .venv/bin/python benchmarks/bench_observed_space.py --scene room0 --preset demo

Figures: docs/observed_space.md#measured
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from mapping.model.agent_config import MappingConfig
from mapping.model.banks import param_counts
from mapping.model.bounds import InstanceBound
from mapping.model.observed import ObservedSpace, observe_frame
from openmulti_env.experiment.presets import get_preset, world_config
from openmulti_env.world import World


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="room0")
    parser.add_argument("--preset", default="demo")
    parser.add_argument("--agent", type=int, default=0)
    parser.add_argument("--stride", type=int, default=16, help="every Nth valid pixel casts a free-space ray")
    parser.add_argument("--cell-m", type=float, default=MappingConfig().observed_cell_m, help="the lattice's cell")
    args = parser.parse_args()
    tree = get_preset(args.preset)
    world = World.build(args.scene, seed=0, config=world_config(args.preset, 4))
    every = tree.team.mapping.keyframe_every
    spaces: dict[int, ObservedSpace] = {}
    bounds: dict[int, InstanceBound] = {}
    seconds, keyframes = 0.0, 0
    for index in range(0, len(world.agent_poses[args.agent]), every):
        frame = world.render(args.agent, index)
        camera = frame.pose[:3, 3]
        rays = frame.backproject(mask=frame.depth > 0)[::args.stride]
        start = time.perf_counter()
        for iid in np.unique(frame.instance[frame.instance > 0]):
            points = frame.backproject(mask=frame.instance == iid)
            box = InstanceBound.from_points(points)
            bounds[iid] = box if iid not in bounds else bounds[iid].union(box)
            space = spaces.setdefault(int(iid), ObservedSpace.empty(args.cell_m))
            observe_frame(space, points, camera, bounds[iid].lo, bounds[iid].hi,
                          free_ends=np.concatenate([rays, points[::4]]))
        seconds += time.perf_counter() - start
        keyframes += 1
    counts = param_counts(MappingConfig())
    sizes = np.array([len(s.to_bytes()) for s in spaces.values()])
    print(f"{args.scene} {args.preset}, agent {args.agent}: {keyframes} keyframes, {len(spaces)} instances, "
          f"{100 * args.cell_m:g} cm cells")
    print(f"marking: {1000 * seconds / max(keyframes, 1):.0f} ms per keyframe")
    print(f"grid on the wire: median {int(np.median(sizes))} B, max {int(sizes.max())} B; an object network "
          f"{4 * counts['object']} B, a structure network {4 * counts['structure']} B in float32 "
          f"(median grid {100 * np.median(sizes) / (4 * counts['object']):.1f} % of an object's)")
    print(f"cells observed: median {100 * np.median([s.observed_share for s in spaces.values()]):.0f} % of a box")


if __name__ == "__main__":
    main()
