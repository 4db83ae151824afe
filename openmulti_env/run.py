"""The main job: build the world, render every agent's frames, map, mesh, evaluate, write results.

Today each agent maps alone (policy ``never``: no messages); the exchange of parameters and rays
arrives with the multi-agent optimisation. A finished agent's map is checkpointed, so an interrupted
run started again with the same ``out`` directory resumes after the last finished agent.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from mapping.agent import MappingAgent
from mapping.checkpoint import CheckpointError
from mapping.evaluate import evaluate_mesh, export_scene_mesh, merge_instance_meshes
from openmulti_env.results import write_json_atomic
from openmulti_env.presets import mapping_config, world_config
from openmulti_env.world import World
from openmulti_env.world.visibility import cull_to_viewpoints

METRIC_KEYS = ("acc_cm", "comp_cm", "comp_ratio", "f_miou", "f_macc")


def map_agent(world: World, agent: int, preset: str, seed: int, checkpoint: Path, device: str) -> MappingAgent:
    """Map one agent's frames alone (or reload its finished map from ``checkpoint``)."""
    structure = {i.instance_id for i in world.scene.instances if i.is_structure}
    mapper = MappingAgent(mapping_config(preset), is_structure=structure.__contains__, device=device,
                          seed=seed * 100 + agent)
    if checkpoint.is_file():
        try:
            mapper.load(checkpoint)
            print(f"[openmulti] agent_{agent}: resumed its finished map from {checkpoint}")
            return mapper
        except CheckpointError as exc:
            print(f"[openmulti] agent_{agent}: ignoring unusable checkpoint ({exc}); mapping again")
    poses = world.agent_poses[agent]
    with tqdm(total=len(poses), desc=f"agent_{agent} mapping", unit="frame") as bar:
        for i in range(len(poses)):
            if mapper.ingest(world.render(agent, i)):
                loss = mapper.train()
                bar.set_postfix(loss=f"{loss:.3f}", instances=len(mapper.slots))
            bar.update(1)
    mapper.save(checkpoint)
    return mapper


def run(scene: str, agents: int, policy: str, preset: str, seed: int, out: Path, device: str = "auto") -> dict:
    """The whole run; returns the metrics dictionary written to ``out/metrics.json``."""
    if policy != "never":
        raise ValueError(f"policy {policy!r} needs the multi-agent exchange, which is not built yet; "
                         "use --policy never (each agent maps alone)")
    start = time.perf_counter()
    torch.manual_seed(seed)
    world = World.build(scene, seed=seed, config=world_config(preset, agents))
    print(f"[openmulti] world {world.scene.name}: {len(world.scene.instances)} instances, "
          f"{world.num_agents} agent(s), {sum(len(p) for p in world.agent_poses)} frames")
    gt = world.surface.culled_mesh()
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    gt.export(out / "meshes" / "gt_observable.ply")
    per_agent, meshes = {}, []
    for a in range(world.num_agents):
        mapper = map_agent(world, a, preset, seed, out / "checkpoints" / f"agent_{a}.pt", device)
        mesh, ids = merge_instance_meshes(mapper.instance_meshes())
        has_mesh = len(mesh.faces) > 0
        if has_mesh:
            export_scene_mesh(out / "meshes" / f"agent_{a}.ply", mesh, ids)
        # score what free space can see of the reconstruction, as the ground truth is culled (README)
        culled = cull_to_viewpoints(mesh, world.surface.viewpoints) if has_mesh else None
        metrics = evaluate_mesh(culled if culled is not None and len(culled.faces) else None, gt, seed=seed)
        raw = evaluate_mesh(mesh if has_mesh else None, gt, seed=seed)
        per_agent[f"agent_{a}"] = {"acc_cm": _finite(metrics.acc_cm), "comp_cm": _finite(metrics.comp_cm),
                                   "comp_ratio": float(metrics.comp_ratio), "f_miou": None, "f_macc": None,
                                   "acc_cm_unculled": _finite(raw.acc_cm), "instances": len(mapper.slots)}
        meshes.append(mesh)
        _save_rendered_views(out / "plots" / f"rendered_views_agent_{a}.png", world, a, mapper)
    mean = {k: _mean([m[k] for m in per_agent.values()]) for k in METRIC_KEYS}
    result = {
        "agents": per_agent, "mean": mean, "bytes_sent_total": 0, "wall_s": time.perf_counter() - start,
        "config": {"scene": scene, "agents": agents, "policy": policy, "preset": preset, "seed": seed,
                   "mapping": {k: v for k, v in asdict(mapping_config(preset)).items()}},
        "notes": "F-mIoU/F-mAcc are null until the perception issue lands. Both meshes are culled to what "
                 "the free-space viewpoints can see; acc_cm_unculled scores the whole reconstruction.",
    }
    write_json_atomic(out / "metrics.json", result)
    from openmulti_env.world.plots import save_reconstruction_views  # noqa: PLC0415

    save_reconstruction_views(out / "plots" / "reconstruction_top_down.png", gt, meshes)
    world.close()
    return result


def _save_rendered_views(path: Path, world: World, agent: int, mapper: MappingAgent, stride: int = 4) -> None:
    """Two views of the agent's path: the sensor's RGB and depth beside the map rendered from the same pose."""
    from openmulti_env.world.plots import save_view_comparison  # noqa: PLC0415

    poses = world.agent_poses[agent]
    views = []
    for i in (len(poses) // 3, 2 * len(poses) // 3):
        frame = world.render(agent, i)
        rendered = mapper.render_view(poses[i], world.intrinsics, stride=stride)
        views.append((frame, rendered.colour.cpu().numpy(), rendered.depth.cpu().numpy()))
    save_view_comparison(path, views, stride, f"{world.scene.name} agent_{agent}: sensor vs map")


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _mean(values: list) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None
