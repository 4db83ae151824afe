"""``openmulti run --data DIR``: map a real RGB-D data set split into K agent sequences, and score it.

    prepare_inputs (data_inputs.py)  ->  align  ->  map every agent  ->  evaluate  ->  write outputs

The inputs (frames, masks, fused instances, ground truth, viewpoints) come from ``data_inputs``;
this module only aligns, maps and scores, so a multi-agent team can replace the mapping step
(``map_agents``) and keep the rest. Until the team exists, only ``--policy never`` maps (every agent
alone, as ``openmulti run --scene``). Outputs are those of ``run --scene``: ``metrics.json`` (the
DESIGN.md contract plus ``team``, ``ground_truth``, ``masks``, ``notes``), ``meshes/``, ``codebook/``
and ``plots/``, and a checkpoint per finished agent (a second run with the same settings resumes).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from mapping.agent import MappingAgent
from mapping.alignment import AlignmentConfig, AlignmentResult, align_agents, no_alignment, oracle_alignment
from mapping.evaluate import evaluate_mesh, export_scene_mesh, merge_instance_meshes
from mapping.evaluate.semantic import SemanticMetrics, semantic_metrics, zero_shot_labels
from mapping.perception import CodeBook, shared_text_encoder
from mapping.perception.image_encoder import VisualFeatureNotice, load_image_encoder
from openmulti_env.data_inputs import DataInputs, prepare_inputs
from openmulti_env.results import finite_or_none, forget_stale_checkpoints, mean_or_none, write_json_atomic
from openmulti_env.run_presets import world_config
from openmulti_env.world.scene import STRUCTURE_CATEGORIES
from openmulti_env.world.visibility import cull_to_viewpoints

METRIC_KEYS = ("acc_cm", "comp_cm", "comp_ratio", "f_miou", "f_macc")
ALIGNMENT_MODES = ("none", "paper", "oracle")
STRUCTURE_PLANE_M = 1.0
"""A geometric planar instance at least this long in two directions gets the structure networks."""


def run_data(data: str | Path, agents: int, policy: str, preset: str, seed: int, out: Path, *, kind: str = "auto",
             gt_mesh: str | None = None, frames: str | None = None, intrinsics: str | None = None,
             depth_scale: float | None = None, device: str = "auto", alignment: str = "none",
             clip_checkpoint: str | None = None) -> dict:
    """The whole data-set run; returns the metrics dictionary written to ``out/metrics.json``.

    Args:
        data: the data set folder (Replica vMAP or NICE-SLAM layout, or a ScanNet export).
        agents: K contiguous agent sequences.
        policy: ``never`` only until the multi-agent team lands (each agent maps alone).
        kind, gt_mesh, frames, intrinsics, depth_scale: see ``openmulti run --help``.
        alignment: ``none``, ``paper`` (sec. III-C) or ``oracle`` (the data set's instance ids; needs masks).
    """
    if policy != "never":
        raise ValueError(f"run --data: policy {policy!r}: the data-set path does not run through the team yet; "
                         "use --policy never (each agent maps alone)")
    if alignment not in ALIGNMENT_MODES:
        raise ValueError(f"unknown alignment {alignment!r}; choose one of {ALIGNMENT_MODES}")
    start = time.perf_counter()
    torch.manual_seed(seed)
    with warnings.catch_warnings(record=True) as notices:
        warnings.simplefilter("always", VisualFeatureNotice)
        image_encoder = load_image_encoder(clip_checkpoint)
    for notice in notices:
        print(f"[openmulti] note: {notice.message}")
    encoder = shared_text_encoder()
    inputs = prepare_inputs(data, kind, agents, frames, intrinsics, depth_scale, gt_mesh, encoder, image_encoder,
                            culling_edge_m=world_config(preset, agents).culling_edge_m, seed=seed)
    for note in inputs.notes:
        print(f"[openmulti] note: {note}")
    settings = {"data": str(Path(data).resolve()), "kind": inputs.kind, "agents": agents, "preset": preset,
                "seed": seed, "alignment": alignment, "frames": frames, "intrinsics": intrinsics,
                "depth_scale": depth_scale, "clip_checkpoint": clip_checkpoint}
    forget_stale_checkpoints(out, settings)
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    inputs.gt_mesh.export(out / "meshes" / ("gt_observable.ply" if inputs.ground_truth == "given" else "gt_reference.ply"))
    aligned = align_inputs(inputs, alignment)
    labels = zero_shot_labels(aligned.codebook, inputs.vocabulary, encoder, image_encoder)
    structure = structure_ids(inputs, aligned, labels)
    mappers = map_agents(inputs, aligned, structure, preset, seed, out, device)
    result = evaluate_agents(inputs, aligned, labels, mappers, seed, out, shared_ids=alignment != "none")
    result.update({
        "bytes_sent_total": int(sum(aligned.bytes_sent.values())), "wall_s": time.perf_counter() - start,
        "ground_truth": inputs.ground_truth, "masks": inputs.masks,
        "timings_s": {k: round(v, 4) for k, v in inputs.timings_s.items()},
        "config": {**settings, "scene": inputs.name, "policy": policy, "gt_mesh": gt_mesh,
                   "frames_per_agent": {a: len(s) for a, s in inputs.frames.items()}},
        "notes": " ".join(inputs.notes + [
            "Meshes are culled to what the cameras' positions (25 cm apart) can see, occlusion included; "
            "acc_cm_unculled scores the whole reconstruction. Policy never: each agent maps alone."]),
    })
    write_json_atomic(out / "metrics.json", result)
    return result


def align_inputs(inputs: DataInputs, mode: str) -> AlignmentResult:
    """Global ids for every agent's instances: ``none``, ``paper`` (sec. III-C) or ``oracle``."""
    args = (inputs.fused, inputs.frames, inputs.segmentations)
    if mode == "paper":
        return align_agents(*args, config=AlignmentConfig())
    if mode == "oracle":
        if inputs.masks != "dataset":
            raise ValueError("--alignment oracle needs the data set's instance masks (the ids are the oracle)")
        return oracle_alignment(*args)
    return no_alignment(*args)


def structure_ids(inputs: DataInputs, aligned: AlignmentResult, labels: dict[int, str]) -> set[int]:
    """Ids mapped with the wider structure networks: walls, floors and ceilings by label, or, with
    geometric masks, planar instances that span at least 1 m in two directions."""
    if inputs.masks == "dataset":
        return {i for i in aligned.codebook if labels.get(i) in STRUCTURE_CATEGORIES}
    out = set()
    for agent in aligned.agents.values():
        for gid, inst in agent.instances.items():
            extent = np.sort(np.ptp(inst.points, axis=0)) if len(inst.points) else np.zeros(3)
            if aligned.codebook[gid].caption.startswith("planar surface") and extent[1] >= STRUCTURE_PLANE_M:
                out.add(gid)
    return out


def map_agents(inputs: DataInputs, aligned: AlignmentResult, structure: set[int], preset: str, seed: int,
               out: Path, device: str) -> dict[str, MappingAgent]:
    """The mapping step: every agent maps its frames on its corrected masks, alone (policy never).

    This is the seam for the multi-agent team: it takes the inputs' frames and the alignment's
    per-frame label images and returns one mapper per agent.
    """
    from openmulti_env.run import map_agent  # noqa: PLC0415  (run.py owns the single-agent mapping loop)

    return {name: map_agent(inputs.frames[name], aligned.agents[name].corrected_labels, structure.__contains__,
                            name, preset, seed * 100 + a, out / "checkpoints" / f"{name}.pt", device)
            for a, name in enumerate(inputs.frames)}


def evaluate_agents(inputs: DataInputs, aligned: AlignmentResult, labels: dict[int, str],
                    mappers: dict[str, MappingAgent], seed: int, out: Path, shared_ids: bool = False) -> dict:
    """Mesh, cull and score every agent's map; write meshes, code books and pictures (a team code book
    only when ``shared_ids``: after alignment the agents' ids name the same objects)."""
    gt = inputs.gt_mesh
    per_agent, meshes, team_points, team_ids = {}, [], [], []
    for name, mapper in mappers.items():
        mesh, ids = merge_instance_meshes(mapper.instance_meshes())
        has_mesh = len(mesh.faces) > 0
        if has_mesh:
            export_scene_mesh(out / "meshes" / f"{name}.ply", mesh, ids)
            team_points.append(np.asarray(mesh.vertices))
            team_ids.append(ids)
        _labelled(aligned.agents[name].codebook, labels).save(out / "codebook", name)
        semantic = _semantics(inputs, np.asarray(mesh.vertices), ids, labels)
        culled = cull_to_viewpoints(mesh, inputs.viewpoints) if has_mesh else None
        metrics = evaluate_mesh(culled if culled is not None and len(culled.faces) else None, gt, seed=seed)
        raw = evaluate_mesh(mesh if has_mesh else None, gt, seed=seed)
        per_agent[name] = {"acc_cm": finite_or_none(metrics.acc_cm), "comp_cm": finite_or_none(metrics.comp_cm),
                           "comp_ratio": float(metrics.comp_ratio),
                           "f_miou": None if semantic is None else semantic.f_miou,
                           "f_macc": None if semantic is None else semantic.f_macc,
                           "acc_cm_unculled": finite_or_none(raw.acc_cm), "instances": len(mapper.slots)}
        meshes.append(mesh)
        _save_rendered_views(out / "plots" / f"rendered_views_{name}.png", inputs, name, mapper)
    team = _semantics(inputs, np.concatenate(team_points) if team_points else np.zeros((0, 3)),
                      np.concatenate(team_ids) if team_ids else np.zeros(0, np.int64), labels)
    team_book = out / "codebook"
    if shared_ids:
        _labelled(aligned.codebook, labels).save(team_book, "team")
    else:
        for suffix in (".json", ".npz"):
            (team_book / f"team{suffix}").unlink(missing_ok=True)
    from openmulti_env.world.plots import save_reconstruction_views, save_semantic_classes  # noqa: PLC0415

    save_reconstruction_views(out / "plots" / "reconstruction_top_down.png", gt, meshes)
    if team is not None:
        save_semantic_classes(out / "plots" / "semantic_per_class.png", team, f"{inputs.name}: team map")
    return {"agents": per_agent,
            "mean": {k: mean_or_none([m[k] for m in per_agent.values()]) for k in METRIC_KEYS},
            "team": {"f_miou": None if team is None else team.f_miou, "f_macc": None if team is None else team.f_macc,
                     "global_instances": len(aligned.codebook),
                     "per_class": [] if team is None else team.as_dict()["per_class"]}}



def summary_lines(result: dict) -> list[str]:
    """The table printed at the end of a data-set run."""
    fmt = lambda x: "-" if x is None else f"{x:.2f}"  # noqa: E731
    lines = [f"{'agent':<10} {'acc [cm]':>9} {'comp [cm]':>10} {'comp ratio [%]':>15} {'F-mIoU':>7} {'F-mAcc':>7} "
             f"{'instances':>10}"]
    for name, m in result["agents"].items():
        lines.append(f"{name:<10} {fmt(m['acc_cm']):>9} {fmt(m['comp_cm']):>10} {fmt(m['comp_ratio']):>15} "
                     f"{fmt(m['f_miou']):>7} {fmt(m['f_macc']):>7} {m['instances']:>10}")
    mean = result["mean"]
    lines.append(f"{'mean':<10} {fmt(mean['acc_cm']):>9} {fmt(mean['comp_cm']):>10} {fmt(mean['comp_ratio']):>15} "
                 f"{fmt(mean['f_miou']):>7} {fmt(mean['f_macc']):>7}")
    against = ("the given ground-truth mesh (culled to what the cameras see)" if result["ground_truth"] == "given"
               else "a TSDF REFERENCE of the same frames, not ground truth")
    lines.append(f"geometry scored against {against}; masks: {result['masks']}"
                 + (" (semantics are geometric only)" if result["masks"] == "geometric" else ""))
    return lines


def _semantics(inputs: DataInputs, points: np.ndarray, ids: np.ndarray, labels: dict[int, str]) -> SemanticMetrics | None:
    if inputs.semantic_gt is None:
        return None
    return semantic_metrics(*inputs.semantic_gt, points, ids, labels)


def _labelled(book: CodeBook, labels: dict[int, str]) -> CodeBook:
    return CodeBook({i: replace(entry, label=labels.get(i)) for i, entry in book.items()})


def _save_rendered_views(path: Path, inputs: DataInputs, name: str, mapper: MappingAgent) -> None:
    """Two frames of the agent: the sensor's RGB and depth beside the map rendered from the same pose."""
    from openmulti_env.world.plots import save_view_comparison  # noqa: PLC0415

    seq = inputs.frames[name]
    stride = max(1, seq.intrinsics.width // 80)
    views = []
    for i in sorted({len(seq) // 3, 2 * len(seq) // 3}):
        frame = seq[i]
        rendered = mapper.render_view(frame.pose, frame.intrinsics, stride=stride)
        views.append((frame, rendered.colour.cpu().numpy(), rendered.depth.cpu().numpy()))
    save_view_comparison(path, views, stride, f"{inputs.name} {name}: sensor vs map")
