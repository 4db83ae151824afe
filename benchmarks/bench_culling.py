"""What cheaper free-space cullings cost in agreement: faces kept and the headline figures of finished runs.

A run's score culls each agent's map to what the free-space viewpoints can see (``cull_to_viewpoints``: one
ray per 2 cm face group and viewpoint until one sees it; a group nobody sees is tried from every viewpoint it
faces, most of the rays). For each finished run given (its ``meshes/agent_k.ply`` and ``config.yaml``) and
each variant (``group_m`` the group size, ``every`` every k-th viewpoint), side by side in one process: the
culling's seconds, the share of faces whose verdict differs from the default's, and the completion ratio and
accuracy of the culled map against the observable ground truth (the same sampled reference as a run).

    .venv/bin/python benchmarks/bench_culling.py runs/demo runs/headroom_fast/room1-s3/unlimited/always

Figures: docs/profile.md#a-cheaper-culling-measured-benchmarksbench_cullingpy
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import trimesh

from mapping.evaluate import SampledSurface, evaluate_mesh, load_scene_mesh
from mapping.evaluate.visibility import cull_to_viewpoints
from openmulti_env.experiment.files import read_config
from openmulti_env.world.world import World

VARIANTS = ((0.02, 1), (0.02, 2), (0.02, 3), (0.02, 4), (0.03, 1))
"""(group_m, every): the default first."""


def kept_faces(culled: trimesh.Trimesh) -> set[bytes]:
    """The culled mesh's faces as a set of their centres' bytes (a submesh keeps them exactly)."""
    return {c.tobytes() for c in np.asarray(culled.triangles_center)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="finished run folders (meshes/ and config.yaml)")
    parser.add_argument("--agents", type=int, nargs="+", default=None, help="which agents' maps (default: all)")
    args = parser.parse_args()
    rows = []
    for run in map(Path, args.runs):
        tree = read_config(run / "config.yaml")
        world = World.build(tree.scene, seed=tree.seed, config=tree.world)
        surface = world.surface
        gt = surface.culled_mesh()
        reference = SampledSurface.of(gt, seed=tree.seed)
        agents = args.agents if args.agents is not None else range(tree.world.num_agents)
        for k in agents:
            mesh, _ = load_scene_mesh(run / "meshes" / f"agent_{k}.ply")
            base_faces = None
            for group_m, every in VARIANTS:
                start = time.perf_counter()
                culled = cull_to_viewpoints(mesh, surface.viewpoints[::every], group_m=group_m)
                seconds = time.perf_counter() - start
                m = evaluate_mesh(culled, gt, seed=tree.seed, reference=reference)
                faces = kept_faces(culled)
                if base_faces is None:
                    base_faces = faces
                differ = len(faces ^ base_faces) / max(len(mesh.faces), 1)
                row = dict(run=str(run), agent=k, group_m=group_m, every=every, seconds=seconds,
                           faces_differ_pct=100 * differ, comp_ratio=m.comp_ratio, acc_cm=m.acc_cm)
                rows.append(row)
                print(f"{run} agent_{k} group {group_m} every {every}: {seconds:.1f} s, {100 * differ:.2f} % faces "
                      f"differ, comp ratio {m.comp_ratio:.3f} %, acc {m.acc_cm:.3f} cm", flush=True)
        world.close()
    print("\n| group_m | every | s (sum) | faces differ % (mean) | comp ratio change (mean, max abs) [points] |")
    print("|---|---|---|---|---|")
    base = {(r["run"], r["agent"]): r for r in rows if (r["group_m"], r["every"]) == VARIANTS[0]}
    for group_m, every in VARIANTS:
        mine = [r for r in rows if (r["group_m"], r["every"]) == (group_m, every)]
        delta = [r["comp_ratio"] - base[(r["run"], r["agent"])]["comp_ratio"] for r in mine]
        print(f"| {group_m} | {every} | {sum(r['seconds'] for r in mine):.1f} | "
              f"{np.mean([r['faces_differ_pct'] for r in mine]):.2f} | {np.mean(delta):+.3f}, "
              f"{np.max(np.abs(delta)):.3f} |")


if __name__ == "__main__":
    main()
