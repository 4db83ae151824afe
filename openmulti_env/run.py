"""The main job: build the world, perceive (segment, caption, fuse, align), map, mesh, evaluate, write results.

Today each agent maps alone (policy ``never``: no parameters or rays are exchanged); the exchange
arrives with the multi-agent optimisation. Before mapping, the simulated open-vocabulary front end
runs for every agent (masks with the seeded error model, captions, SBERT, cross-frame fusion); with
``alignment="paper"`` the agents also exchange their instance point clouds once and apply the
Cross-Agent Instance Alignment, so every agent maps on corrected masks with team-wide ids. A
finished agent's map is checkpointed, so an interrupted run started again with the same ``out``
directory resumes after the last finished agent (the front end is deterministic and runs again).
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import asdict, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from mapping.agent import MappingAgent
from mapping.checkpoint import CheckpointError
from mapping.data import Frame
from mapping.evaluate import evaluate_mesh, export_scene_mesh, merge_instance_meshes
from mapping.evaluate.semantic import semantic_metrics, zero_shot_labels
from mapping.perception import CodeBook, shared_text_encoder
from mapping.perception.errors import SegmentationErrorConfig
from mapping.perception.image_encoder import VisualFeatureNotice, load_image_encoder
from openmulti_env.run_presets import mapping_config, world_config
from openmulti_env.results import write_json_atomic
from openmulti_env.team_perception import (ALIGNMENT_MODES, FrontEndConfig, align_team, category_vocabulary,
                                           perceive_team, semantic_ground_truth, structure_ids)
from openmulti_env.world import World
from openmulti_env.world.visibility import cull_to_viewpoints

METRIC_KEYS = ("acc_cm", "comp_cm", "comp_ratio", "f_miou", "f_macc")


def map_agent(frames: list[Frame], labels_of: Callable[[int], np.ndarray], is_structure: Callable[[int], bool],
              name: str, preset: str, seed: int, checkpoint: Path, device: str) -> MappingAgent:
    """Map one agent's frames on its (corrected) instance masks, or reload its finished map."""
    mapper = MappingAgent(mapping_config(preset), is_structure=is_structure, device=device, seed=seed)
    if checkpoint.is_file():
        try:
            mapper.load(checkpoint)
            print(f"[openmulti] {name}: resumed its finished map from {checkpoint}")
            return mapper
        except CheckpointError as exc:
            print(f"[openmulti] {name}: ignoring unusable checkpoint ({exc}); mapping again")
    with tqdm(total=len(frames), desc=f"{name} mapping", unit="frame") as bar:
        for frame in frames:
            if mapper.ingest(frame, labels_of(frame.index)):
                loss = mapper.train()
                bar.set_postfix(loss=f"{loss:.3f}", instances=len(mapper.slots))
            bar.update(1)
    mapper.save(checkpoint)
    return mapper


def run(scene: str, agents: int, policy: str, preset: str, seed: int, out: Path, device: str = "auto",
        alignment: str = "none", segmentation_errors: bool = True, clip_checkpoint: str | None = None) -> dict:
    """The whole run; returns the metrics dictionary written to ``out/metrics.json``.

    Args:
        alignment: ``none`` (each agent keeps its own instances), ``paper`` (agents exchange instance
            point clouds once and align, sec. III-C) or ``oracle`` (ground-truth ids, an upper bound).
        segmentation_errors: apply the front end's default error model (else perfect masks).
        clip_checkpoint: local open_clip checkpoint for visual features (None: caption features only).
    """
    if policy != "never":
        raise ValueError(f"policy {policy!r} needs the multi-agent exchange, which is not built yet; "
                         "use --policy never (each agent maps alone)")
    if alignment not in ALIGNMENT_MODES:
        raise ValueError(f"unknown alignment {alignment!r}; choose one of {ALIGNMENT_MODES}")
    start = time.perf_counter()
    torch.manual_seed(seed)
    with warnings.catch_warnings(record=True) as notices:
        warnings.simplefilter("always", VisualFeatureNotice)
        image_encoder = load_image_encoder(clip_checkpoint)
    for notice in notices:  # said once, as one line
        print(f"[openmulti] note: {notice.message}")
    world = World.build(scene, seed=seed, config=world_config(preset, agents))
    _forget_other_runs(out, {"scene": scene, "agents": agents, "preset": preset, "seed": seed, "alignment": alignment,
                             "segmentation_errors": segmentation_errors, "clip_checkpoint": clip_checkpoint})
    print(f"[openmulti] world {world.scene.name}: {len(world.scene.instances)} instances, "
          f"{world.num_agents} agent(s), {sum(len(p) for p in world.agent_poses)} frames")
    encoder = shared_text_encoder()
    front = FrontEndConfig(errors=SegmentationErrorConfig() if segmentation_errors else SegmentationErrorConfig.none())
    perception = perceive_team(world, seed, front, encoder, image_encoder=image_encoder)
    aligned = align_team(perception, alignment, front.alignment)
    vocabulary = category_vocabulary(world)
    labels = zero_shot_labels(aligned.codebook, vocabulary, encoder, image_encoder)
    structure = structure_ids(aligned.codebook, labels)
    gt = world.surface.culled_mesh()
    gt_points, gt_labels = semantic_ground_truth(world, 200_000, seed)
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    gt.export(out / "meshes" / "gt_observable.ply")
    per_agent, meshes, team_points, team_ids = {}, [], [], []
    for a in range(world.num_agents):
        name = f"agent_{a}"
        mapper = map_agent(perception.frames[name], aligned.agents[name].corrected_labels, structure.__contains__,
                           name, preset, seed * 100 + a, out / "checkpoints" / f"{name}.pt", device)
        mesh, ids = merge_instance_meshes(mapper.instance_meshes())
        has_mesh = len(mesh.faces) > 0
        if has_mesh:
            export_scene_mesh(out / "meshes" / f"{name}.ply", mesh, ids)
            team_points.append(np.asarray(mesh.vertices))
            team_ids.append(ids)
        book = _labelled(aligned.agents[name].codebook, labels)
        book.save(out / "codebook", name)
        semantic = semantic_metrics(gt_points, gt_labels, np.asarray(mesh.vertices), ids, labels)
        # score what free space can see of the reconstruction, as the ground truth is culled (README)
        culled = cull_to_viewpoints(mesh, world.surface.viewpoints) if has_mesh else None
        metrics = evaluate_mesh(culled if culled is not None and len(culled.faces) else None, gt, seed=seed)
        raw = evaluate_mesh(mesh if has_mesh else None, gt, seed=seed)
        per_agent[name] = {"acc_cm": _finite(metrics.acc_cm), "comp_cm": _finite(metrics.comp_cm),
                           "comp_ratio": float(metrics.comp_ratio), "f_miou": semantic.f_miou,
                           "f_macc": semantic.f_macc, "acc_cm_unculled": _finite(raw.acc_cm),
                           "instances": len(mapper.slots)}
        meshes.append(mesh)
        _save_rendered_views(out / "plots" / f"rendered_views_{name}.png", world, a, mapper)
    team = semantic_metrics(gt_points, gt_labels, np.concatenate(team_points) if team_points else np.zeros((0, 3)),
                            np.concatenate(team_ids) if team_ids else np.zeros(0, np.int64), labels)
    if alignment != "none":
        _labelled(aligned.codebook, labels).save(out / "codebook", "team")
    else:  # agents' ids are their own: a team code book of an earlier run must not answer queries
        for suffix in (".json", ".npz"):
            (out / "codebook" / f"team{suffix}").unlink(missing_ok=True)
    mean = {k: _mean([m[k] for m in per_agent.values()]) for k in METRIC_KEYS}
    result = {
        "agents": per_agent, "mean": mean, "bytes_sent_total": int(sum(aligned.bytes_sent.values())),
        "wall_s": time.perf_counter() - start,
        "team": {"f_miou": team.f_miou, "f_macc": team.f_macc, "global_instances": len(aligned.codebook),
                 "per_class": team.as_dict()["per_class"]},
        "config": {"scene": scene, "agents": agents, "policy": policy, "preset": preset, "seed": seed,
                   "alignment": alignment, "segmentation_errors": segmentation_errors,
                   "error_rates": asdict(front.errors),
                   "mapping": {k: v for k, v in asdict(mapping_config(preset)).items()}},
        "notes": "Meshes are culled to what the free-space viewpoints can see; acc_cm_unculled scores the whole "
                 "reconstruction. F-mIoU/F-mAcc: each ground-truth point takes the zero-shot label of the "
                 "nearest reconstructed vertex's instance. bytes_sent_total counts the alignment's point-cloud "
                 "messages (policy never sends no parameters or rays).",
    }
    write_json_atomic(out / "metrics.json", result)
    from openmulti_env.world.plots import save_reconstruction_views, save_semantic_classes  # noqa: PLC0415

    save_reconstruction_views(out / "plots" / "reconstruction_top_down.png", gt, meshes)
    save_semantic_classes(out / "plots" / "semantic_per_class.png", team, f"{world.scene.name}: team map, "
                          f"alignment {alignment}")
    world.close()
    return result


def _forget_other_runs(out: Path, settings: dict) -> None:
    """Keep the agents' checkpoints only if they were made with these settings (ids, masks and maps
    depend on all of them); otherwise delete them, so a resumed run never mixes two runs."""
    path = out / "checkpoints" / "run_settings.json"
    try:
        same = json.loads(path.read_text()) == settings
    except (OSError, ValueError):  # no record (or an unreadable one): the checkpoints cannot be trusted
        same = False
    stale = [] if same else sorted((out / "checkpoints").glob("agent_*.pt"))
    for ckpt in stale:
        ckpt.unlink()
    if stale:
        print(f"[openmulti] {out}: settings differ from the run that wrote its checkpoints; "
              f"deleted {len(stale)} checkpoint(s) and mapping again")
    write_json_atomic(path, settings)


def _labelled(book: CodeBook, labels: dict[int, str]) -> CodeBook:
    """A copy of ``book`` whose entries carry their zero-shot labels."""
    return CodeBook({i: replace(entry, label=labels.get(i)) for i, entry in book.items()})


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
