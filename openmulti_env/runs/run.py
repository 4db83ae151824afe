"""``openmulti run``: a team maps the simulated world (``run``) or a real RGB-D data set (``run_data``)
round by round under a scripted communication policy, through the one pipeline
(``mapping.pipeline.runner``). This module turns command-line options into a source, the team
settings of a preset (``openmulti_env.presets``) and a schedule.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import torch

from mapping.agent_config import MappingConfig, for_recordings
from mapping.data.source import DataSource, prepare_inputs
from mapping.field import OBJECT_FIELD
from mapping.perception import shared_text_encoder
from mapping.perception.errors import SegmentationErrorConfig
from mapping.perception.geometric_segmenter import segmenter_settings
from mapping.perception.image_encoder import VisualFeatureNotice, load_image_encoder
from mapping.pipeline import RunConfig, Schedule, SourceRecord, run_team
from mapping.runtime import available_cores, set_threads
from mapping.team import AgentSnapshot, ChannelConfig, ExchangeConfig, RoundPlan, TeamConfig
from mapping.team.consistency import CONSISTENCY_ALGORITHMS
from mapping.sdf_loss import SdfConfig
from mapping.team.global_map import (GLOBAL_ENCODING_SCALE, GLOBAL_FORMS, GLOBAL_WIDTH, MACIM_RHO, global_rays_for,
                                      published_mapping, scene_frame)
from openmulti_env.environment.actions import actions_to_plan
from openmulti_env.presets import Preset, get_preset
from openmulti_env.runs.sim_source import SimulatedSource
from openmulti_env.world import World
from openmulti_env.environment.observation import TeamObserver
from policies import make_policy, parse_policy

RUN_ALIGNMENT_MODES = ("paper", "none")


def run(scene: str, agents: int, policy: str, preset: str, seed: int, out: Path, device: str = "auto",
        alignment: str = "paper", segmentation_errors: bool = True, clip_checkpoint: str | None = None,
        comm_budget_mb: float | None = None, consistency: str = "consensus", cross_rendering: bool = True,
        float16: bool = False, changed_only: float | None = None, threads: int | None = None,
        checkpoint_every: int = 5, progress: bool = True, max_rounds: int | None = None,
        global_map: bool = False, global_width: int = GLOBAL_WIDTH,
        global_encoding_scale: float = GLOBAL_ENCODING_SCALE, global_form: str = "equal_compute",
        share_point_clouds: bool = False, three_cullings: bool = False, plots: bool = True, workers: int | None = None,
        missing_edges: str = "skip", processes: str | None = None, holdout_every: int | None = None,
        learner: str = "per_agent", evaluate: bool = True, sdf: SdfConfig | None = None,
        shared_global_init: bool = True) -> dict:
    """A team run on the simulated ``scene``; returns the metrics written to ``out/metrics.json``.

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
        missing_edges: DiNNO and DSGD with a vector that did not arrive this round: ``skip`` the edge or
            use the ``last`` one held (``ConsistencyConfig.missing_edges``).
        processes: None (every agent in this process) or ``ray`` (each agent in a Ray actor of its own:
            ``mapping.team.remote``).
        learner: ``per_agent`` or ``fleet`` (every agent's iterations batched into one computation per step,
            ``mapping.fleet``, on ``threads`` torch threads; the same maps to float tolerance).
        holdout_every: keep every k-th frame of each agent out of its map and score the map's depth there
            (``depth_heldout_*``; ``TeamConfig.holdout_every``).
        float16, changed_only: what parameter messages carry (``ExchangeConfig``).
        threads: torch threads (default: all cores).
        checkpoint_every: save the team every this many rounds (an interrupted run resumes from it).
        max_rounds: stop after this many rounds (None: when the paths end), e.g. for smoke tests.
        global_map: one network of width ``global_width`` (encoding scale ``global_encoding_scale``)
            for the whole scene per agent, with the instance-level map's per-step compute
            (``mapping.team.global_map``): the global baselines.
        global_form: the global map's form: ``equal_compute`` (above) or ``published`` (MACIM's scene SDF,
            samples, losses, iteration budget and rho 0.3; ``global_width`` and ``global_encoding_scale``
            are then MACIM's).
        sdf: the published form's settings (None: MACIM's, ``SdfConfig()``), e.g. another iteration budget
            for a study (benchmarks/study_global_budget.py); refused for any other map.
        shared_global_init: a global map's agents start from one network (``TeamConfig.shared_global_init``;
            False: each its own draw, as before 2026-12-05); refused without ``global_map``.
        share_point_clouds: "send parameters" links carry the observed points instead (Table VI).
        three_cullings: also score every map NICE-SLAM-culled and unculled (``mapping.pipeline.scoring``).
        plots: write the pictures (the experiments skip them: they cost seconds per run).
        evaluate: False maps only (rounds, bytes, final checkpoint; ``RunConfig.evaluate``): the same call
            again with True resumes after the last round and scores.
        workers: agents trained side by side on threads (same results as 1). Default: one per core when
            ``threads`` is not given (each with 1 torch thread: small batches use one core better than
            two), else 1.
    """
    if global_form not in GLOBAL_FORMS:
        raise ValueError(f"unknown global_form {global_form!r}; choose one of {GLOBAL_FORMS}")
    begun = begin_run(preset, policy, agents, alignment, consistency, comm_budget_mb, threads, workers, seed,
                      clip_checkpoint)
    chosen, scripted, workers, image_encoder = begun.preset, begun.policy, begun.workers, begun.image_encoder
    world = World.build(scene, seed=seed, config=chosen.world_config(agents))
    settings = {"scene": scene, "agents": agents, "policy": policy, "preset": preset, "seed": seed,
                "alignment": alignment, "segmentation_errors": segmentation_errors, "clip_checkpoint": clip_checkpoint,
                "comm_budget_mb": comm_budget_mb, "consistency": consistency, "cross_rendering": cross_rendering,
                "float16": float16, "changed_only": changed_only,
                **({"missing_edges": missing_edges} if consistency in ("dinno", "dsgd") else {})}
    published = global_map and global_form == "published"
    if sdf is not None and not published:
        raise ValueError("sdf settings apply to the published global map only (global_map=True, "
                         "global_form='published')")
    if not shared_global_init and not global_map:
        raise ValueError("shared_global_init=False applies to a global map only (global_map=True)")
    if published:
        global_width = (sdf or SdfConfig()).width
    if global_map or share_point_clouds or three_cullings:  # older runs' settings stay as they were
        settings.update({"global_map": global_map, "global_width": global_width,
                         **({"global_encoding_scale": global_encoding_scale} if global_map and not published else {}),
                         **({"global_form": global_form} if published else {}),
                         "share_point_clouds": share_point_clouds, "three_cullings": three_cullings})
    if sdf is not None and sdf != SdfConfig():  # MACIM's own settings leave the record as it was
        settings["sdf"] = asdict(sdf)
    if not shared_global_init:
        settings["shared_global_init"] = False
    print(f"[openmulti] world {world.scene.name}: {len(world.scene.instances)} instances, "
          f"{world.num_agents} agent(s), {sum(len(p) for p in world.agent_poses)} frames")
    source = SimulatedSource(world, seed, shared_text_encoder(name=chosen.text_encoder), image_encoder,
                             segmentation_errors)
    mapping, map_info = map_structure(world, chosen, global_map, global_width, global_encoding_scale, published,
                                      sdf)
    team = run_team_config(chosen, alignment, consistency, cross_rendering, float16, changed_only, mapping=mapping,
                           global_map=global_map, share_point_clouds=share_point_clouds, missing_edges=missing_edges,
                           holdout_every=holdout_every, rho=MACIM_RHO if published else None)
    team = replace(team, shared_global_init=shared_global_init)
    errors = SegmentationErrorConfig() if segmentation_errors else SegmentationErrorConfig.none()
    record = SourceRecord(settings, {"map": map_info}, described={"error_rates": asdict(errors)})
    config = RunConfig(Path(out), team, team_channel(scripted, comm_budget_mb), seed=seed, device=device,
                       workers=workers, threads=threads, checkpoint_every=checkpoint_every, max_rounds=max_rounds,
                       three_cullings=three_cullings, plots=plots, progress=progress, processes=processes,
                       learner=learner, evaluate=evaluate,
                       title=f"{world.scene.name}: policy {policy}")
    try:
        observer = None
        if scripted.reads_observations:
            budget = None if comm_budget_mb is None else comm_budget_mb * 1e6
            observer = TeamObserver((0.0, 0.0, 0.0), world.scene.size_m, chosen.map_size, budget)
        return run_team(source, record, config, PolicySchedule(scripted, observer), start=begun.start).as_json()
    finally:
        world.close()


def run_data(data: str | Path, agents: int, policy: str, preset: str, seed: int, out: Path, *, kind: str = "auto",
             gt_mesh: str | None = None, frames: str | None = None, intrinsics: str | None = None,
             depth_scale: float | None = None, device: str = "auto", alignment: str = "paper",
             clip_checkpoint: str | None = None, comm_budget_mb: float | None = None, consistency: str = "consensus",
             cross_rendering: bool = True, float16: bool = False, changed_only: float | None = None,
             threads: int | None = None, checkpoint_every: int = 5, progress: bool = True,
             max_rounds: int | None = None, workers: int | None = None, missing_edges: str = "skip",
             processes: str | None = None, holdout_every: int | None = None, learner: str = "per_agent",
             evaluate: bool = True, segmenter: str = "fixed", recording_mapper: bool = True) -> dict:
    """A team run on a real RGB-D data set split into ``agents`` contiguous sequences; returns the metrics
    written to ``out/metrics.json``.

    Args:
        data: the data set folder (Replica vMAP or NICE-SLAM layout, or a ScanNet export).
        kind, gt_mesh, frames, intrinsics, depth_scale, segmenter: see ``openmulti run --help``.
        recording_mapper: the preset's mapper through ``for_recordings`` (carving, crossing free-space rays);
            False keeps the preset's mapper as it is (vMAP's loss and rays), for studies of one change.
        the rest: as ``run``.
    """
    segmenter_config = segmenter_settings(segmenter)
    begun = begin_run(preset, policy, agents, alignment, consistency, comm_budget_mb, threads, workers, seed,
                      clip_checkpoint)
    chosen, scripted, workers, image_encoder = begun.preset, begun.policy, begun.workers, begun.image_encoder
    if scripted.reads_observations:
        raise ValueError(f"policy {policy!r} reads observations, which need the room's box; data-set runs take the "
                         "fixed schedules (always, never, round_robin, budget, every:K, at:R1,R2,..., rate:Q, bernoulli:P)")
    encoder = shared_text_encoder(name=chosen.text_encoder)
    inputs = prepare_inputs(data, kind, agents, frames, intrinsics, depth_scale, gt_mesh, encoder, image_encoder,
                            culling_edge_m=chosen.culling_edge_m, seed=seed, progress=progress,
                            segmenter_config=segmenter_config)
    for note in inputs.notes:
        print(f"[openmulti] note: {note}")
    source = DataSource(inputs, encoder, image_encoder)
    record = source.record({"data": str(Path(data).resolve()), "agents": agents, "policy": policy, "preset": preset,
                            "seed": seed, "alignment": alignment, "frames": frames, "intrinsics": intrinsics,
                            "depth_scale": depth_scale, "gt_mesh": gt_mesh, "clip_checkpoint": clip_checkpoint,
                            "comm_budget_mb": comm_budget_mb, "consistency": consistency,
                            "cross_rendering": cross_rendering, "float16": float16, "changed_only": changed_only,
                            **({"missing_edges": missing_edges} if consistency in ("dinno", "dsgd") else {}),
                            **({"segmenter": segmenter} if segmenter != "fixed" else {}),
                            **({} if recording_mapper else {"recording_mapper": False})})
    team = run_team_config(chosen, alignment, consistency, cross_rendering, float16, changed_only,
                           mapping=for_recordings(chosen.mapping) if recording_mapper else chosen.mapping,
                           missing_edges=missing_edges, holdout_every=holdout_every)
    config = RunConfig(Path(out), team, team_channel(scripted, comm_budget_mb), seed=seed, device=device,
                       workers=workers, threads=threads, checkpoint_every=checkpoint_every, max_rounds=max_rounds,
                       progress=progress, processes=processes, learner=learner, evaluate=evaluate,
                       title=f"{inputs.name}: policy {policy}")
    return run_team(source, record, config, PolicySchedule(scripted), start=begun.start).as_json()


@dataclass
class RunStart:
    """What every run settles first: its preset, policy, worker threads, clock and image encoder."""

    preset: Preset
    policy: object
    """A policy of ``policies.make_policy``."""
    workers: int
    start: float
    image_encoder: object | None


def begin_run(preset: str, policy: str, agents: int, alignment: str, consistency: str, comm_budget_mb: float | None,
              threads: int | None, workers: int | None, seed: int, clip_checkpoint: str | None) -> RunStart:
    """Check the options (ValueError naming the problem), set the threads, start the clock, seed torch and
    load the optional image encoder, in that order (the order the runs' figures were made in)."""
    chosen = get_preset(preset)
    scripted = team_policy(policy, agents, alignment, consistency, comm_budget_mb, seed)
    workers = team_workers(agents, threads, workers)
    set_threads(threads, workers=workers)
    start = time.perf_counter()
    torch.manual_seed(seed)
    return RunStart(chosen, scripted, workers, start, image_encoder_said_once(clip_checkpoint))


def team_policy(policy: str, agents: int, alignment: str, consistency: str,
                comm_budget_mb: float | None, seed: int = 0):
    """The communication policy of a team run, after checking the options (ValueError naming the problem)."""
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
    return make_policy(spec, agents, seed)


def team_workers(agents: int, threads: int | None, workers: int | None) -> int:
    """Agent worker threads: ``workers``, or one per core (up to one per agent) when ``threads`` is not given."""
    if workers is None:
        workers = min(available_cores(), agents) if threads is None else 1
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    return workers


def image_encoder_said_once(clip_checkpoint: str | None):
    """The optional image-text encoder; its absence is said once, as one line."""
    with warnings.catch_warnings(record=True) as notices:
        warnings.simplefilter("always", VisualFeatureNotice)
        image_encoder = load_image_encoder(clip_checkpoint)
    for notice in notices:
        print(f"[openmulti] note: {notice.message}")
    return image_encoder


class PolicySchedule:
    """A communication policy as the pipeline's schedule. Each round it hands the policy what the env would:
    every agent's observation (``TeamObserver``: its own frames, fields and messages; built only for
    policies that read them) and its budget left (the env's ``infos``)."""

    def __init__(self, policy, observer: TeamObserver | None = None):
        self.policy, self.observer = policy, observer

    def __call__(self, team, snapshots: list[AgentSnapshot]) -> RoundPlan:
        infos = {s.name: {"budget_left_mb": s.budget_left_bytes / 1e6} for s in snapshots}
        observations = None
        if self.observer is not None:
            if len(self.observer.observers) != len(snapshots):
                self.observer.reset(len(snapshots))
            if team.round_index > 0:
                self.observer.update(team, snapshots)
            observations = {s.name: self.observer.observe(s) for s in snapshots}
        return actions_to_plan(self.policy(observations, infos, team.round_index), [s.name for s in snapshots])


def team_channel(policy, comm_budget_mb: float | None) -> ChannelConfig:
    """The links of a run: the policy's success probability, ``comm_budget_mb`` per agent (None: unlimited)."""
    return ChannelConfig(policy.spec.success_probability, None if comm_budget_mb is None else comm_budget_mb * 1e6)


def run_team_config(preset: Preset, alignment: str, consistency: str, cross_rendering: bool, float16: bool,
                    changed_only: float | None, mapping: MappingConfig | None = None, global_map: bool = False,
                    share_point_clouds: bool = False, missing_edges: str = "skip",
                    holdout_every: int | None = None, rho: float | None = None) -> TeamConfig:
    """The team settings of a run from its command-line options (on the preset's ``team_config``; ``rho``:
    the consensus weight, None for the library's)."""
    return preset.team_config(mapping=mapping, alignment=alignment == "paper", global_map=global_map,
                              holdout_every=holdout_every,
                              consistency={"algorithm": consistency, "cross_rendering": cross_rendering,
                                           "missing_edges": missing_edges, **({"rho": rho} if rho is not None else {})},
                              exchange=ExchangeConfig(float16=float16, changed_only=changed_only,
                                                      point_clouds=share_point_clouds))


def map_structure(world: World, preset: Preset, global_map: bool, width: int,
                  encoding_scale: float = GLOBAL_ENCODING_SCALE, published: bool = False,
                  sdf: SdfConfig | None = None) -> tuple[MappingConfig, dict]:
    """The mapper settings and a description of the map (widths, rays per step) for the table.

    A global map gets the scene box as its frame and the rays per step that buy the per-step MLP
    FLOPs of an instance-level map of this scene's instances (``global_rays_for``), or, ``published``,
    MACIM's scene SDF with its own budget (``published_mapping``; ``sdf``: other settings than MACIM's)."""
    mapping = preset.mapping
    if global_map and published:
        sdf = sdf or SdfConfig()
        return published_mapping(mapping, scene_frame(world.scene.size_m), sdf), {
            "kind": "global", "form": "published", "network": "MACIM scene SDF", "width": sdf.width,
            "rays_per_step": sdf.rays, "samples_per_ray": sdf.n_stratified + sdf.n_surface,
            "iterations_per_frame": sdf.iterations_per_frame, "iterations_after": sdf.iterations_after}
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
