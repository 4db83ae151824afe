"""``openmulti run``: a team maps the simulated world or a real RGB-D data set round by round under a
scripted communication policy, through the one pipeline (``mapping.pipeline.runner``). Everything a run does
is one configuration tree (``openmulti_env.experiment.Experiment``): ``run_experiment`` turns it into a
source, the team settings it resolves and a schedule, and writes the tree whole as ``OUT/config.yaml``.
"""

from __future__ import annotations

import tempfile
import time
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import torch

from mapping.model.agent_config import MappingConfig, for_recordings
from mapping.pipeline.data_source import DataSource, prepare_inputs
from mapping.model.field import OBJECT_FIELD
from mapping.perception import shared_text_encoder
from mapping.perception.errors import SegmentationErrorConfig
from mapping.perception.geometric_segmenter import segmenter_settings
from mapping.perception.image_encoder import VisualFeatureNotice, load_image_encoder
from mapping.pipeline import RunConfig, SourceRecord, run_team
from mapping.runtime import available_cores, set_threads
from mapping.team import AgentSnapshot, RoundPlan
from mapping.team.global_map import global_rays_for, published_mapping, scene_frame
from openmulti_env.environment.actions import actions_to_plan
from openmulti_env.environment.observation import slot_instances
from openmulti_env.environment.observation import TeamObserver, team_observer
from openmulti_env.experiment import (Experiment, checkpoint_identity, experiment, read_checkpoint_identity,
                                      resolved_team, tree_record, write_config)
from openmulti_env.runs.made_at import made_at
from openmulti_env.runs.sim_source import SimulatedSource
from openmulti_env.world import World
from policies import make_policy, parse_policy


def run(scene: str, agents: int, policy: str, preset: str, seed: int, out: Path, **overrides) -> dict:
    """A team run on the simulated ``scene`` (``run_experiment`` of the preset's tree with these settings and
    ``overrides``: dotted paths or short spellings, ``openmulti_env.experiment.overrides.ALIASES``)."""
    return run_experiment(experiment(preset, scene=scene, agents=agents, policy=policy, seed=seed, out=str(out),
                                     **overrides))


def run_data(data: str | Path, agents: int, policy: str, preset: str, seed: int, out: Path, **overrides) -> dict:
    """A team run on a real RGB-D data set split into ``agents`` contiguous sequences (see ``run``)."""
    return run_experiment(experiment(preset, data=str(data), agents=agents, policy=policy, seed=seed, out=str(out),
                                     **overrides))


def run_experiment(tree: Experiment) -> dict:
    """The run ``tree`` describes: the simulator's scene, or ``tree.data.path``; returns the metrics written to
    ``tree.run.out/metrics.json`` (the tree itself goes to ``config.yaml`` beside it)."""
    writable_folder(Path(tree.run.out), "run.out (--out)")  # before minutes of world building, not after
    return (_run_data_set if tree.data.path is not None else _run_scene)(tree)


def writable_folder(folder: Path, name: str) -> None:
    """Create ``folder`` if needed and make sure files can be written in it; ValueError naming ``name``."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".write-check-"):
            pass
    except OSError as exc:
        reason = "it is a file" if folder.is_file() else (exc.strerror or type(exc).__name__).lower()
        raise ValueError(f"{name} {str(folder)!r} cannot hold the run's files: {reason}") from None


def _run_scene(tree: Experiment) -> dict:
    if tree.perception.segmenter != "fixed":
        raise ValueError("perception.segmenter (--segmenter) is for --data without instance images; the simulator's "
                         "masks come from its own error model (--perception.segmentation-errors false turns it off)")
    begun = begin_run(tree)
    world = World.build(tree.scene, seed=tree.seed, config=tree.world)
    print(f"[openmulti] world {world.scene.name}: {len(world.scene.instances)} instances, "
          f"{world.num_agents} agent(s), {sum(len(p) for p in world.agent_poses)} frames")
    segmentation_errors = tree.perception.segmentation_errors
    source = SimulatedSource(world, tree.seed, shared_text_encoder(name=tree.perception.text_encoder),
                             begun.image_encoder, segmentation_errors)
    mapping, map_info = map_structure(world, tree)
    team = resolved_team(tree, mapping)
    errors = SegmentationErrorConfig() if segmentation_errors else SegmentationErrorConfig.none()
    record = SourceRecord(tree_record(tree), {"map": map_info, "made_at": made_at()}, described={"error_rates": asdict(errors)},
                          identity=checkpoint_identity(tree, {}), read_identity=read_checkpoint_identity)
    try:
        observer, slots = None, 0
        if begun.policy.reads_observations:
            observer = team_observer(tree, world.scene.size_m, policy_form(begun.policy))
            slots = observer.instance_slots
        return run_team(source, record, run_config(tree, team, begun.workers, world.scene.name),
                        PolicySchedule(begun.policy, observer, slots), start=begun.start).as_json()
    finally:
        world.close()


def _run_data_set(tree: Experiment) -> dict:
    if not tree.perception.segmentation_errors:
        raise ValueError("--perception.segmentation-errors false is for --scene (the simulator's error model); with --data the masks are the "
                         "data set's instance images or the geometric segmenter's")
    segmenter_config = segmenter_settings(tree.perception.segmenter)
    begun = begin_run(tree)
    if begun.policy.reads_observations:
        raise ValueError(f"policy {tree.run.policy!r} reads observations, which need the room's box; data-set runs take "
                         "the fixed schedules (always, never, round_robin, budget, every:K, at:R1,R2,..., rate:Q, "
                         "bernoulli:P)")
    data = tree.data
    encoder = shared_text_encoder(name=tree.perception.text_encoder)
    inputs = prepare_inputs(data.path, data.kind, tree.num_agents, data.frames, data.intrinsics, data.depth_scale,
                            data.gt_mesh, encoder, begun.image_encoder, culling_edge_m=tree.world.culling_edge_m,
                            seed=tree.seed, progress=tree.run.progress, segmenter_config=segmenter_config)
    for note in inputs.notes:
        print(f"[openmulti] note: {note}")
    source = DataSource(inputs, encoder, begun.image_encoder)
    record = source.record(tree_record(tree), checkpoint_identity(tree, source.facts()), read_checkpoint_identity)
    record = replace(record, results={**record.results, "made_at": made_at()})  # the code the figures come from
    mapping = tree.team.mapping
    team = resolved_team(tree, for_recordings(mapping) if data.recording_mapper else mapping)
    return run_team(source, record, run_config(tree, team, begun.workers, inputs.name),
                    PolicySchedule(begun.policy), start=begun.start).as_json()


def run_config(tree: Experiment, team, workers: int, name: str) -> RunConfig:
    """The pipeline's settings of a run: the resolved team, the tree's links and job settings; writes the tree
    as ``OUT/config.yaml`` first (a run that fails midway still says what it was)."""
    out = Path(tree.run.out)
    write_config(tree, out)
    return RunConfig(replace(tree.run, workers=workers), team, tree.channel, seed=tree.seed,
                     title=f"{name}: policy {tree.run.policy}")


@dataclass
class RunStart:
    """What every run settles first: its policy, worker threads, clock and image encoder."""

    policy: object
    """A policy of ``policies.make_policy``."""
    workers: int
    start: float
    image_encoder: object | None


def begin_run(tree: Experiment) -> RunStart:
    """Make the policy, set the threads, start the clock, seed torch and load the optional image encoder, in
    that order (the order the runs' figures were made in)."""
    policy = make_policy(parse_policy(tree.run.policy), tree.num_agents, tree.seed)
    workers = team_workers(tree.num_agents, tree.run.threads, tree.run.workers)
    set_threads(tree.run.threads, workers=workers)
    start = time.perf_counter()
    torch.manual_seed(tree.seed)
    return RunStart(policy, workers, start, image_encoder_said_once(tree.perception.clip_checkpoint))


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

    def __init__(self, policy, observer: TeamObserver | None = None, slots: int = 0):
        self.policy, self.observer, self.slots = policy, observer, slots
        self.form = policy_form(policy)

    def __call__(self, team, snapshots: list[AgentSnapshot]) -> RoundPlan:
        infos = {s.name: {"budget_left_mb": s.budget_left_bytes / 1e6} for s in snapshots}
        observations = None
        if self.observer is not None:
            if len(self.observer.observers) != len(snapshots):
                self.observer.reset(len(snapshots))
            if team.round_index > 0:
                self.observer.update(team, snapshots)
            observations = {s.name: self.observer.observe(s) for s in snapshots}
        slot_ids = [slot_instances(s, len(snapshots), self.slots) for s in snapshots] if self.slots else None
        return actions_to_plan(self.policy(observations, infos, team.round_index), [s.name for s in snapshots],
                               self.form, self.slots, slot_ids)


def policy_form(policy) -> str:
    """The action form a policy acts in (``entries`` unless it says otherwise)."""
    return getattr(policy, "action_form", "entries")


def map_structure(world: World, tree: Experiment) -> tuple[MappingConfig, dict]:
    """The mapper settings and a description of the map (widths, rays per step) for the table.

    A global map (``tree.team.global_map``) gets the scene box as its frame and the rays per step that buy the
    per-step MLP FLOPs of an instance-level map of this scene's instances (``global_rays_for``), or, in the
    ``published`` form, MACIM's scene SDF with its own budget (``published_mapping``, ``tree.global_map.sdf``)."""
    mapping, settings = tree.team.mapping, tree.global_map
    if tree.team.global_map and settings.form == "published":
        sdf = settings.sdf
        return published_mapping(mapping, scene_frame(world.scene.size_m), sdf), {
            "kind": "global", "form": "published", "network": "MACIM scene SDF", "width": sdf.width,
            "rays_per_step": sdf.rays, "samples_per_ray": sdf.n_stratified + sdf.n_surface,
            "iterations_per_frame": sdf.iterations_per_frame, "iterations_after": sdf.iterations_after}
    objects = sum(1 for i in world.scene.instances if not i.is_structure)
    structures = len(world.scene.instances) - objects
    if not tree.team.global_map:
        return mapping, {"kind": "instance", "object_width": OBJECT_FIELD.hidden_width,
                         "structure_width": mapping.structure_width, "rays_per_object": mapping.rays_per_object,
                         "rays_per_structure": mapping.rays_per_structure,
                         "rays_per_step_at_scene_instances": objects * mapping.rays_per_object
                         + structures * mapping.rays_per_structure}
    width, encoding_scale = settings.width, settings.encoding_scale
    rays = global_rays_for(objects, structures, mapping.rays_per_object, mapping.rays_per_structure,
                           OBJECT_FIELD.hidden_width, mapping.structure_width, width)
    info = {"kind": "global", "width": width, "encoding_scale": encoding_scale, "rays_per_step": rays,
            "matched_to": f"{objects} objects x {mapping.rays_per_object} rays at width {OBJECT_FIELD.hidden_width} "
                          f"+ {structures} structures x {mapping.rays_per_structure} at width {mapping.structure_width}"}
    return replace(mapping, structure_width=width, structure_encoding_scale=encoding_scale, rays_per_structure=rays,
                   global_frame=scene_frame(world.scene.size_m)), info
