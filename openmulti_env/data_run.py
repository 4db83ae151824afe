"""``openmulti run --data DIR``: a real RGB-D data set split into K agent sequences, mapped by the
collaborative team round by round under a scripted policy (as ``openmulti run --scene``), and scored.

    prepare_inputs (data_inputs.py)  ->  one DataStream per agent  ->  Team rounds  ->  evaluate  ->  outputs

The inputs (frames, masks with caption features, ground truth, viewpoints) come from ``data_inputs``;
the team (``mapping.team``) fuses each agent's frames online, exchanges what the policy asks for and
aligns arrived instances itself; this module only feeds it the data set and scores every agent's own
map against the data set's ground truth. Outputs are those of ``run --scene``: ``metrics.json`` (the
DESIGN.md contract plus ``bytes_per_round``, ``fleet_s``, ``rounds``, ``team``, ``ground_truth``,
``masks``, ``notes``), ``rounds.json``, ``meshes/``, ``codebook/``, ``plots/`` and the team's
checkpoint every few rounds (a second run with the same settings resumes after the last saved round).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import asdict
from pathlib import Path

import torch

from mapping.data import Frame
from mapping.perception import FrameSegmentation, TextEncoder, shared_text_encoder
from mapping.perception.geometric_segmenter import instance_caption
from mapping.perception.image_encoder import VisualFeatureNotice, load_image_encoder
from mapping.runtime import set_threads
from mapping.team import Team, TeamMember, Vocabulary
from openmulti_env.data_inputs import DataInputs, prepare_inputs
from openmulti_env.results import forget_stale_checkpoints
from openmulti_env.run import (_plain, as_record, _run_rounds, mean_metrics, run_team_config, score_member, team_channel,
                               team_policy, team_results, team_semantics, write_team_outputs)
from openmulti_env.run_presets import world_config
from openmulti_env.world.scene import STRUCTURE_CATEGORIES

PLANAR = "planar surface"
"""With geometric masks, the vocabulary name whose instances get the structure networks."""


class DataStream:
    """One agent's frames of a data set as a ``mapping.team.AgentStream``: frame ``i`` (decoded from disk
    when read) and its segmentation (masks with caption features, from ``prepare_inputs``)."""

    def __init__(self, inputs: DataInputs, name: str):
        self.name = name
        self.frames, self.segmentations = inputs.frames[name], inputs.segmentations[name]

    def __len__(self) -> int:
        return len(self.frames)

    def read(self, index: int) -> tuple[Frame, FrameSegmentation]:
        if not 0 <= index < len(self):
            raise IndexError(f"{self.name} has frames 0..{len(self) - 1}, not {index}")
        return self.frames[index], self.segmentations[index]


def data_vocabulary(inputs: DataInputs, text_encoder: TextEncoder) -> Vocabulary:
    """The team's vocabulary: the data set's categories with walls, floors and ceilings as structure;
    with geometric masks "planar surface" / "object", planar surfaces as structure (wider networks)."""
    structure = STRUCTURE_CATEGORIES if inputs.masks == "dataset" else (PLANAR,)
    return Vocabulary.from_encoder(inputs.vocabulary, text_encoder, structure)


def run_data(data: str | Path, agents: int, policy: str, preset: str, seed: int, out: Path, *, kind: str = "auto",
             gt_mesh: str | None = None, frames: str | None = None, intrinsics: str | None = None,
             depth_scale: float | None = None, device: str = "auto", alignment: str = "paper",
             clip_checkpoint: str | None = None, comm_budget_mb: float | None = None, consistency: str = "consensus",
             cross_rendering: bool = True, float16: bool = False, changed_only: float | None = None,
             threads: int | None = None, checkpoint_every: int = 5, progress: bool = True,
             max_rounds: int | None = None) -> dict:
    """The whole data-set run; returns the metrics dictionary written to ``out/metrics.json``.

    Args:
        data: the data set folder (Replica vMAP or NICE-SLAM layout, or a ScanNet export).
        agents: K contiguous agent sequences.
        policy: a scripted policy (always, never, bernoulli:P, round_robin, budget), as ``run``.
        kind, gt_mesh, frames, intrinsics, depth_scale: see ``openmulti run --help``.
        alignment: ``paper`` (arrived instances are aligned, sec. III-C) or ``none`` (adopted as new);
            the team has no ``oracle`` alignment.
        comm_budget_mb, consistency, cross_rendering, float16, changed_only, threads, checkpoint_every,
            max_rounds: as ``openmulti_env.run.run``.
    """
    scripted = team_policy(policy, agents, alignment, consistency, comm_budget_mb)
    set_threads(threads)
    start = time.perf_counter()
    torch.manual_seed(seed)
    with warnings.catch_warnings(record=True) as notices:
        warnings.simplefilter("always", VisualFeatureNotice)
        image_encoder = load_image_encoder(clip_checkpoint)
    for notice in notices:
        print(f"[openmulti] note: {notice.message}")
    encoder = shared_text_encoder()
    inputs = prepare_inputs(data, kind, agents, frames, intrinsics, depth_scale, gt_mesh, encoder, image_encoder,
                            culling_edge_m=world_config(preset, agents).culling_edge_m, seed=seed, progress=progress)
    for note in inputs.notes:
        print(f"[openmulti] note: {note}")
    settings = {"data": str(Path(data).resolve()), "kind": inputs.kind, "agents": agents, "policy": policy,
                "preset": preset, "seed": seed, "alignment": alignment, "frames": frames, "intrinsics": intrinsics,
                "depth_scale": depth_scale, "clip_checkpoint": clip_checkpoint, "comm_budget_mb": comm_budget_mb,
                "consistency": consistency, "cross_rendering": cross_rendering, "float16": float16,
                "changed_only": changed_only}
    config = run_team_config(preset, alignment, consistency, cross_rendering, float16, changed_only)
    # a checkpoint made under other team settings (library defaults included) is not resumed
    forget_stale_checkpoints(out, {**settings, "team": as_record(asdict(config))})
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    inputs.gt_mesh.export(out / "meshes" / ("gt_observable.ply" if inputs.ground_truth == "given" else "gt_reference.ply"))
    team = Team([DataStream(inputs, name) for name in inputs.frames], config, data_vocabulary(inputs, encoder),
                seed=seed, channel=team_channel(scripted, comm_budget_mb), device=device)
    reports = _run_rounds(team, scripted, out / "checkpoints" / "team.pt", checkpoint_every, progress, max_rounds)
    result = evaluate_team(inputs, team, seed, out, encoder, image_encoder)
    result.update({
        **team_results(team, reports),
        "wall_s": time.perf_counter() - start,
        "ground_truth": inputs.ground_truth, "masks": inputs.masks,
        "timings_s": {k: round(v, 4) for k, v in inputs.timings_s.items()},
        "config": {**settings, "scene": inputs.name, "gt_mesh": gt_mesh,
                   "frames_per_agent": {a: len(s) for a, s in inputs.frames.items()}, "team": _plain(asdict(config))},
        "notes": " ".join(inputs.notes + [
            "Per-agent metrics: each agent's own map against the whole ground truth; mean = their average. "
            "Meshes are culled to what the cameras' positions (25 cm apart) can see, occlusion included; "
            "*_unculled score the whole reconstruction. bytes_* count the serialised parameter and ray messages. "
            "fleet_s: per round, the slowest agent's local phase + the exchange + the slowest consistency "
            "phase, summed."]),
    })
    write_team_outputs(out, result, reports, f"{inputs.name}: policy {policy}")
    return result


def evaluate_team(inputs: DataInputs, team: Team, seed: int, out: Path, encoder, image_encoder) -> dict:
    """Mesh, cull and score every agent's own map against the data set's ground truth (F-mIoU / F-mAcc
    where it has categories); write meshes, code books (geometric instances named "planar surface K" /
    "object K") and pictures."""
    caption = (lambda iid, text: instance_caption(text, iid)) if inputs.masks == "geometric" else None
    per_agent, maps = {}, []
    for member in team.members:
        per_agent[member.name], own = score_member(member, inputs.vocabulary, inputs.gt_mesh, inputs.viewpoints, None,
                                                   seed, out, encoder, image_encoder, inputs.semantic_gt, caption)
        maps.append(own)
        _save_rendered_views(out / "plots" / f"rendered_views_{member.name}.png", inputs, member)
    union = team_semantics(maps, inputs.semantic_gt, out)
    from openmulti_env.world.plots import save_reconstruction_views, save_semantic_classes  # noqa: PLC0415

    save_reconstruction_views(out / "plots" / "reconstruction_top_down.png", inputs.gt_mesh, [m.mesh for m in maps])
    if union is not None:
        save_semantic_classes(out / "plots" / "semantic_per_class.png", union, f"{inputs.name}: all agents' maps")
    return {"agents": per_agent, "mean": mean_metrics(per_agent),
            "team": {"f_miou": None if union is None else union.f_miou,
                     "f_macc": None if union is None else union.f_macc,
                     "per_class": [] if union is None else union.as_dict()["per_class"]}}


def summary_lines(result: dict) -> list[str]:
    """The table printed at the end of a data-set run."""
    fmt = lambda x: "-" if x is None else f"{x:.2f}"  # noqa: E731
    lines = [f"{'agent':<10} {'acc [cm]':>9} {'comp [cm]':>10} {'comp ratio [%]':>15} {'F-mIoU':>7} {'F-mAcc':>7} "
             f"{'instances':>10} {'compute [s]':>12}"]
    for name, m in result["agents"].items():
        lines.append(f"{name:<10} {fmt(m['acc_cm']):>9} {fmt(m['comp_cm']):>10} {fmt(m['comp_ratio']):>15} "
                     f"{fmt(m['f_miou']):>7} {fmt(m['f_macc']):>7} {m['instances']:>10} "
                     f"{result['compute_s'][name]:>12.1f}")
    mean = result["mean"]
    lines.append(f"{'mean':<10} {fmt(mean['acc_cm']):>9} {fmt(mean['comp_cm']):>10} {fmt(mean['comp_ratio']):>15} "
                 f"{fmt(mean['f_miou']):>7} {fmt(mean['f_macc']):>7}")
    against = ("the given ground-truth mesh (culled to what the cameras see)" if result["ground_truth"] == "given"
               else "a TSDF REFERENCE of the same frames, not ground truth")
    lines.append(f"geometry scored against {against}; masks: {result['masks']}"
                 + (" (semantics are geometric only)" if result["masks"] == "geometric" else ""))
    return lines


def _save_rendered_views(path: Path, inputs: DataInputs, member: TeamMember) -> None:
    """Two frames of the agent: the sensor's RGB and depth beside the map rendered from the same pose."""
    from openmulti_env.world.plots import save_view_comparison  # noqa: PLC0415

    seq = inputs.frames[member.name]
    stride = max(1, seq.intrinsics.width // 80)
    views = []
    for i in sorted({len(seq) // 3, 2 * len(seq) // 3}):
        frame = seq[i]
        rendered = member.mapper.render_view(frame.pose, frame.intrinsics, stride=stride)
        views.append((frame, rendered.colour.cpu().numpy(), rendered.depth.cpu().numpy()))
    save_view_comparison(path, views, stride, f"{inputs.name} {member.name}: sensor vs map")
