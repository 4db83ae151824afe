"""The main job: build the world, run the team round by round under a scripted policy, mesh, evaluate,
write results.

Each round every agent reads its next frames (rendered, segmented with the seeded error model,
captioned, fused online), trains, and exchanges what the policy asks for through the channel
(``mapping.team``); the team is checkpointed every few rounds, so an interrupted run started again
with the same ``out`` directory and settings resumes after the last saved round. The data-set path
(``openmulti_env.data_run``) drives the same team through ``team_policy``, ``run_team_config``,
``_run_rounds``, ``team_results`` and ``write_team_outputs``.
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch
import trimesh
from tqdm import tqdm

from mapping.agent import MappingAgent, MappingConfig
from mapping.field import OBJECT_FIELD
from mapping.runtime import available_cores, set_threads
from mapping.team import ChannelConfig, ConsistencyConfig, ExchangeConfig, Team, TeamConfig, TeamMember
from mapping.team.consistency import CONSISTENCY_ALGORITHMS
from mapping.team.global_map import GLOBAL_ENCODING_SCALE, GLOBAL_WIDTH, global_rays_for, scene_frame
from mapping.checkpoint import CheckpointError
from mapping.evaluate import export_scene_mesh, merge_instance_meshes
from mapping.evaluate.semantic import SemanticMetrics, semantic_metrics, zero_shot_labels
from mapping.perception import CodeBook, shared_text_encoder
from mapping.perception.errors import SegmentationErrorConfig
from mapping.perception.image_encoder import VisualFeatureNotice, load_image_encoder
from openmulti_env.actions import actions_to_plan
from openmulti_env.run_presets import mapping_config, team_config, world_config
from openmulti_env.results import forget_stale_checkpoints, mean_or_none, write_json_atomic
from openmulti_env.scoring import CameraViews, agents_camera_views, score_three_ways
from openmulti_env.sim_team import world_streams, world_vocabulary
from openmulti_env.team_perception import category_vocabulary, semantic_ground_truth
from policies.scripted import ScriptedPolicy, parse_policy
from openmulti_env.world import World

METRIC_KEYS = ("acc_cm", "comp_cm", "comp_ratio", "f_miou", "f_macc")
CULLING_KEYS = tuple(f"{m}{s}" for s in ("_nice", "_unculled") for m in ("acc_cm", "comp_cm", "comp_ratio"))
"""The same geometry under the other cullings (``openmulti_env.scoring``), averaged like the rest."""
RUN_ALIGNMENT_MODES = ("paper", "none")
TEAM_ID_STRIDE = 100_000
"""Agent k's instance i is ``k * TEAM_ID_STRIDE + i`` in the union of all agents' maps."""


def run(scene: str, agents: int, policy: str, preset: str, seed: int, out: Path, device: str = "auto",
        alignment: str = "paper", segmentation_errors: bool = True, clip_checkpoint: str | None = None,
        comm_budget_mb: float | None = None, consistency: str = "consensus", cross_rendering: bool = True,
        float16: bool = False, changed_only: float | None = None, threads: int | None = None,
        checkpoint_every: int = 5, progress: bool = True, max_rounds: int | None = None,
        global_map: bool = False, global_width: int = GLOBAL_WIDTH,
        global_encoding_scale: float = GLOBAL_ENCODING_SCALE, share_point_clouds: bool = False,
        three_cullings: bool = False, plots: bool = True, workers: int | None = None) -> dict:
    """The whole run; returns the metrics dictionary written to ``out/metrics.json``.

    Args:
        policy: a scripted policy name (``policies.scripted``): always, never, bernoulli:P, round_robin,
            budget.
        alignment: ``paper`` (arrived instances are aligned, sec. III-C) or ``none`` (every arrived
            instance is adopted as a new one: the ablation).
        segmentation_errors: apply the front end's default error model (else perfect masks).
        clip_checkpoint: local open_clip checkpoint for visual features (None: caption features only).
        comm_budget_mb: bytes each agent may send over the run (None: unlimited).
        consistency: parameter consistency (eq. 12): consensus, dinno, dsgd or none.
        cross_rendering: Cross Rendering Supervision on shared rays (eq. 13).
        float16, changed_only: what parameter messages carry (``ExchangeConfig``).
        threads: torch threads (default: all cores).
        checkpoint_every: save the team every this many rounds (an interrupted run resumes from it).
        max_rounds: stop after this many rounds (None: when the paths end), e.g. for smoke tests.
        global_map: one network of width ``global_width`` (encoding scale ``global_encoding_scale``)
            for the whole scene per agent, with the instance-level map's per-step compute
            (``mapping.team.global_map``): the global baselines.
        share_point_clouds: "send parameters" links carry the observed points instead (Table VI).
        three_cullings: also score every map NICE-SLAM-culled and unculled (``openmulti_env.scoring``).
        plots: write the pictures (the experiments skip them: they cost seconds per run).
        workers: agents trained side by side on threads (``Team(workers=)``; same results as 1). Default:
            one per core when ``threads`` is not given (each with 1 torch thread: small batches use one
            core better than two), else 1.
    """
    scripted = team_policy(policy, agents, alignment, consistency, comm_budget_mb)
    if workers is None:
        workers = min(available_cores(), agents) if threads is None else 1
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    set_threads(threads, workers=workers)
    start = time.perf_counter()
    torch.manual_seed(seed)
    with warnings.catch_warnings(record=True) as notices:
        warnings.simplefilter("always", VisualFeatureNotice)
        image_encoder = load_image_encoder(clip_checkpoint)
    for notice in notices:  # said once, as one line
        print(f"[openmulti] note: {notice.message}")
    world = World.build(scene, seed=seed, config=world_config(preset, agents))
    settings = {"scene": scene, "agents": agents, "policy": policy, "preset": preset, "seed": seed,
                "alignment": alignment, "segmentation_errors": segmentation_errors, "clip_checkpoint": clip_checkpoint,
                "comm_budget_mb": comm_budget_mb, "consistency": consistency, "cross_rendering": cross_rendering,
                "float16": float16, "changed_only": changed_only}
    if global_map or share_point_clouds or three_cullings:  # older runs' settings stay as they were
        settings.update({"global_map": global_map, "global_width": global_width,
                         **({"global_encoding_scale": global_encoding_scale} if global_map else {}),
                         "share_point_clouds": share_point_clouds, "three_cullings": three_cullings})
    print(f"[openmulti] world {world.scene.name}: {len(world.scene.instances)} instances, "
          f"{world.num_agents} agent(s), {sum(len(p) for p in world.agent_poses)} frames")
    encoder = shared_text_encoder()
    mapping, map_info = _map_structure(world, preset, global_map, global_width, global_encoding_scale)
    config = run_team_config(preset, alignment, consistency, cross_rendering, float16, changed_only, mapping=mapping,
                             global_map=global_map, share_point_clouds=share_point_clouds)
    # the checkpoints must come from the same team settings too, defaults included: a run made before
    # a default changed (e.g. eq. 13's) is mapped again, not resumed into a mix of two versions
    forget_stale_checkpoints(out, {**settings, "team": as_record(asdict(config))})
    team = Team(world_streams(world, seed, segmentation_errors, text_encoder=encoder, image_encoder=image_encoder),
                config, world_vocabulary(world, encoder), seed=seed,
                channel=team_channel(scripted, comm_budget_mb), device=device, workers=workers)
    try:
        reports = _run_rounds(team, scripted, out / "checkpoints" / "team.pt", checkpoint_every, progress, max_rounds)
    finally:
        team.close()  # the worker threads (the team stays usable for evaluation)
    set_threads(threads)  # evaluation runs on this thread alone: give it every core again
    views = agents_camera_views(world, config.mapping.keyframe_every) if three_cullings else None
    result = _evaluate(world, team, seed, out, encoder, image_encoder, views, plots)
    result.update({
        **team_results(team, reports),
        "map": map_info,
        "wall_s": time.perf_counter() - start,
        "config": {**settings, "error_rates": asdict(SegmentationErrorConfig() if segmentation_errors
                                                     else SegmentationErrorConfig.none()),
                   "team": _plain(asdict(config))},
    })
    write_team_outputs(out, result, reports, f"{world.scene.name}: policy {policy}", plots)
    world.close()
    return result


def team_policy(policy: str, agents: int, alignment: str, consistency: str,
                comm_budget_mb: float | None) -> ScriptedPolicy:
    """The scripted policy of a team run, after checking the options (ValueError naming the problem)."""
    spec = parse_policy(policy)
    if alignment not in RUN_ALIGNMENT_MODES:
        raise ValueError(f"unknown alignment {alignment!r} for a team run; choose one of {RUN_ALIGNMENT_MODES} "
                         "(the team has no ground-truth 'oracle' alignment; it is in benchmarks/bench_alignment.py)")
    if consistency not in CONSISTENCY_ALGORITHMS:
        raise ValueError(f"unknown consistency {consistency!r}; choose one of {CONSISTENCY_ALGORITHMS}")
    if comm_budget_mb is not None and not comm_budget_mb >= 0:
        raise ValueError(f"--comm-budget-mb must be >= 0, got {comm_budget_mb}")
    if spec.rule == "budget" and comm_budget_mb is None:
        raise ValueError("policy 'budget' needs --comm-budget-mb MB (the megabytes each agent may send over the run)")
    return ScriptedPolicy(spec, agents)


def team_channel(policy: ScriptedPolicy, comm_budget_mb: float | None) -> ChannelConfig:
    """The links of a run: the policy's success probability, ``comm_budget_mb`` per agent (None: unlimited)."""
    return ChannelConfig(policy.spec.success_probability, None if comm_budget_mb is None else comm_budget_mb * 1e6)


def run_team_config(preset: str, alignment: str, consistency: str, cross_rendering: bool, float16: bool,
                    changed_only: float | None, mapping: MappingConfig | None = None, global_map: bool = False,
                    share_point_clouds: bool = False) -> TeamConfig:
    """The team settings of a run from its command-line options (on the preset's ``team_config``)."""
    return team_config(preset, mapping=mapping, alignment=alignment == "paper", global_map=global_map,
                       consistency=ConsistencyConfig(algorithm=consistency, cross_rendering=cross_rendering),
                       exchange=ExchangeConfig(float16=float16, changed_only=changed_only,
                                               point_clouds=share_point_clouds))


def team_results(team: Team, reports: list[dict]) -> dict:
    """What the rounds cost: bytes (total, per round, per link), messages, fleet and compute seconds."""
    n = team.num_agents
    bytes_per_round = [int(sum(r["bytes_sent"])) for r in reports]
    return {
        "bytes_sent_total": int(team.channel.bytes_sent.sum()),
        "bytes_per_round": bytes_per_round,
        "bytes_per_link_total": team.channel.link_bytes.tolist(),
        "bytes_per_round_per_agent_mean": float(np.mean(bytes_per_round) / max(n, 1)) if reports else 0.0,
        "messages": {k: int(sum(r[k] for r in reports)) for k in ("delivered", "dropped", "over_budget")},
        "fleet_s": float(sum(r["fleet_s"] for r in reports)),
        "compute_s": {f"agent_{a}": float(sum(r["compute_s"][a] for r in reports)) for a in range(n)},
        "rounds": len(reports),
    }


def write_team_outputs(out: Path, result: dict, reports: list[dict], title: str, plots: bool = True) -> None:
    """``rounds.json``, ``metrics.json`` and (with ``plots``) the bytes-per-round picture."""
    write_json_atomic(out / "rounds.json", {"rounds": reports})
    write_json_atomic(out / "metrics.json", result)
    if plots:
        from openmulti_env.world.plots import save_round_bytes  # noqa: PLC0415

        save_round_bytes(out / "plots" / "bytes_per_round.png", reports, title)


def _map_structure(world: World, preset: str, global_map: bool, width: int,
                   encoding_scale: float = GLOBAL_ENCODING_SCALE) -> tuple[MappingConfig, dict]:
    """The mapper settings and a description of the map (widths, rays per step) for the table.

    A global map gets the scene box as its frame and the rays per step that buy the per-step MLP
    FLOPs of an instance-level map of this scene's instances (``global_rays_for``)."""
    mapping = mapping_config(preset)
    objects = sum(1 for i in world.scene.instances if not i.is_structure)
    structures = len(world.scene.instances) - objects
    if not global_map:
        return mapping, {"kind": "instance", "object_width": OBJECT_FIELD.hidden_width,
                         "structure_width": mapping.structure_width, "rays_per_object": mapping.rays_per_object,
                         "rays_per_structure": mapping.rays_per_structure,
                         "rays_per_step_at_scene_instances": objects * mapping.rays_per_object
                         + structures * mapping.rays_per_structure}
    rays = global_rays_for(objects, structures, mapping.rays_per_object, mapping.rays_per_structure,
                           OBJECT_FIELD.hidden_width, mapping.structure_width, width)
    info = {"kind": "global", "width": width, "encoding_scale": encoding_scale, "rays_per_step": rays,
            "matched_to": f"{objects} objects x {mapping.rays_per_object} rays at width {OBJECT_FIELD.hidden_width} "
                          f"+ {structures} structures x {mapping.rays_per_structure} at width {mapping.structure_width}"}
    return replace(mapping, structure_width=width, structure_encoding_scale=encoding_scale, rays_per_structure=rays,
                   global_frame=scene_frame(world.scene.size_m)), info


def _run_rounds(team: Team, policy: ScriptedPolicy, checkpoint: Path, every: int, progress: bool,
                max_rounds: int | None = None) -> list[dict]:
    """Rounds until the paths end, resuming from ``checkpoint`` when it exists; per-round reports."""
    reports: list[dict] = []
    if checkpoint.is_file():
        try:
            reports = team.load(checkpoint)["reports"]
            print(f"[openmulti] resumed the team after round {team.round_index} from {checkpoint}")
        except CheckpointError as exc:
            print(f"[openmulti] ignoring unusable checkpoint ({exc}); starting again")
    n = team.num_agents
    total = team.rounds_total() if max_rounds is None else min(max_rounds, team.rounds_total())
    with tqdm(total=total, initial=team.round_index, desc="rounds", unit="round", disable=not progress) as bar:
        while not team.done and team.round_index < total:
            infos = {f"agent_{a}": {"budget_left_mb": team.channel.budget_left(a) / 1e6} for a in range(n)}
            plan = actions_to_plan(policy(infos, team.round_index), [f"agent_{a}" for a in range(n)])
            report = team.round(plan).as_dict()
            reports.append(report)
            bar.set_postfix(MB=f"{sum(report['bytes_sent']) / 1e6:.1f}", fleet_s=f"{report['fleet_s']:.1f}",
                            instances=sum(len(m.mapper.live_ids()) for m in team.members))
            bar.update(1)
            if every and (team.round_index % every == 0 or team.round_index == total):
                team.save(checkpoint, extra={"reports": reports})
    return reports


def _evaluate(world: World, team: Team, seed: int, out: Path, encoder, image_encoder,
              views: CameraViews | None = None, plots: bool = True) -> dict:
    """Mesh, cull and score every agent's own map against the whole observable ground truth (the
    paper's per-agent metrics, averaged); the team map's semantics; code books; pictures."""
    vocabulary = category_vocabulary(world)
    gt = world.surface.culled_mesh()
    semantic_gt = semantic_ground_truth(world, 200_000, seed)
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    gt.export(out / "meshes" / "gt_observable.ply")
    per_agent, maps = {}, []
    for member in tqdm(team.members, desc="evaluating", unit="agent"):
        # score what free space can see of the reconstruction, as the ground truth is culled (README);
        # also NICE-SLAM-culled when asked, and unculled
        per_agent[member.name], own = score_member(member, vocabulary, gt, world.surface.viewpoints, views, seed, out,
                                                   encoder, image_encoder, semantic_gt)
        maps.append(own)
        if plots:
            _save_rendered_views(out / "plots" / f"rendered_views_{member.name}.png", world, member.index, member.mapper)
    union = team_semantics(maps, semantic_gt, out)
    if plots:
        from openmulti_env.world.plots import save_reconstruction_views, save_semantic_classes  # noqa: PLC0415

        save_reconstruction_views(out / "plots" / "reconstruction_top_down.png", gt, [m.mesh for m in maps])
        save_semantic_classes(out / "plots" / "semantic_per_class.png", union, f"{world.scene.name}: all agents' maps")
    return {"agents": per_agent, "mean": mean_metrics(per_agent),
            "team": {"f_miou": union.f_miou, "f_macc": union.f_macc, "per_class": union.as_dict()["per_class"]},
            "notes": "Per-agent metrics: each agent's own map against the whole observable ground truth; mean = "
                     "their average (as the paper). Meshes are culled to what the free-space viewpoints can see; "
                     "acc_cm_unculled scores the whole reconstruction (and *_nice NICE-SLAM-culled, when asked). bytes_* count the serialised parameter and "
                     "ray messages (and the clouds inside them). fleet_s: per round, the slowest agent's local "
                     "phase + the exchange + the slowest consistency phase, summed."}


@dataclass
class MemberMap:
    """One agent's meshed map: the mesh, each vertex's instance id, the instances' zero-shot labels."""

    index: int
    mesh: trimesh.Trimesh
    ids: np.ndarray
    labels: dict[int, str]


def score_member(member: TeamMember, vocabulary: list[str], gt: trimesh.Trimesh, viewpoints: np.ndarray,
                 views: CameraViews | None, seed: int, out: Path, encoder, image_encoder,
                 semantic_gt: tuple[np.ndarray, np.ndarray] | None,
                 caption: Callable[[int, str], str] | None = None) -> tuple[dict, MemberMap]:
    """Mesh one member's own map (``out/meshes/<name>.ply``), label its code book against ``vocabulary``
    (``out/codebook/<name>``; ``caption(id, caption)`` renames the captions written), score it against
    ``gt`` culled to ``viewpoints`` (``score_three_ways``) and, with ``semantic_gt`` (points, categories),
    its F-mIoU / F-mAcc (else None)."""
    name, mapper = member.name, member.mapper
    book = member.codebook()
    labels = zero_shot_labels(book, vocabulary, encoder, image_encoder) if book else {}
    mesh, ids = merge_instance_meshes(mapper.instance_meshes())
    has_mesh = len(mesh.faces) > 0
    if has_mesh:
        export_scene_mesh(out / "meshes" / f"{name}.ply", mesh, ids)
    _labelled(book, labels, caption).save(out / "codebook", name)
    semantic = None if semantic_gt is None else semantic_metrics(*semantic_gt, np.asarray(mesh.vertices), ids, labels)
    scores = score_three_ways(mesh if has_mesh else None, gt, viewpoints, views, seed)
    adopted = sum(1 for i in mapper.live_ids() if not mapper.keyframes.has_pixels(i))
    return ({**scores, "f_miou": None if semantic is None else semantic.f_miou,
             "f_macc": None if semantic is None else semantic.f_macc,
             "instances": len(mapper.live_ids()), "instances_without_own_pixels": adopted},
            MemberMap(member.index, mesh, ids, labels))


def team_semantics(maps: list[MemberMap], semantic_gt: tuple[np.ndarray, np.ndarray] | None,
                   out: Path) -> SemanticMetrics | None:
    """F-mIoU / F-mAcc of all agents' maps together (agent k's instance i is ``k * TEAM_ID_STRIDE + i``);
    None without ``semantic_gt``. Agents' ids are their own, so no team code book answers queries: an
    older one in ``out/codebook`` is removed."""
    for suffix in (".json", ".npz"):
        (out / "codebook" / f"team{suffix}").unlink(missing_ok=True)
    if semantic_gt is None:
        return None
    meshed = [m for m in maps if len(m.mesh.faces)]
    points = np.concatenate([np.asarray(m.mesh.vertices) for m in meshed]) if meshed else np.zeros((0, 3))
    ids = np.concatenate([m.ids + m.index * TEAM_ID_STRIDE for m in meshed]) if meshed else np.zeros(0, np.int64)
    labels = {iid + m.index * TEAM_ID_STRIDE: lab for m in meshed for iid, lab in m.labels.items()}
    return semantic_metrics(*semantic_gt, points, ids, labels)


def mean_metrics(per_agent: dict[str, dict]) -> dict:
    """The mean over agents of every metric all agents have (``METRIC_KEYS`` and the other cullings')."""
    keys = [k for k in METRIC_KEYS + CULLING_KEYS if all(k in m for m in per_agent.values())]
    return {k: mean_or_none([m[k] for m in per_agent.values()]) for k in keys}


def as_record(value) -> dict:
    """``value`` as it reads back from a JSON file (tuples as lists, inf as inf): what a settings record
    on disk is compared with."""
    return json.loads(json.dumps(_plain(value)))


def _plain(value):
    """Config dicts for JSON (tuples and frozensets as lists)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [_plain(v) for v in value]
    return value



def _labelled(book: CodeBook, labels: dict[int, str], caption: Callable[[int, str], str] | None = None) -> CodeBook:
    """A copy of ``book`` whose entries carry their zero-shot labels (and ``caption(id, caption)``'s captions)."""
    return CodeBook({i: replace(entry, label=labels.get(i), **({} if caption is None else
                                                                {"caption": caption(i, entry.caption)}))
                     for i, entry in book.items()})


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
