"""The one run pipeline: ``run_team(source, config, schedule) -> RunResult``.

    Source (frame streams, vocabulary)  ->  Team rounds under the schedule (checkpointed, resumable)
        ->  every agent's own map meshed and scored against the source's ground truth  ->  outputs

``openmulti run --scene`` (the simulator's source), ``openmulti run --data`` (a data set's),
``openmulti reproduce`` and the benchmarks all run through it. Outputs in ``out``: ``metrics.json``
(``RunResult.as_json``: the DESIGN.md contract and more), ``rounds.json`` (one ``RoundReport`` per
round), ``meshes/``, ``codebook/``, ``plots/`` and the team's checkpoint every few rounds (the same call
on the same folder resumes after the last saved round; other settings start again).
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm import tqdm

from mapping.model.checkpoint import CheckpointError
from mapping.evaluate import SampledSurface
from mapping.pipeline.records import as_record, forget_stale_checkpoints, plain, write_json_atomic
from mapping.pipeline.scoring import DEPTH_CHECK_EVERY, mean_metrics, score_member, team_semantics
from mapping.pipeline.settings import RunSettings
from mapping.pipeline.source import GroundTruth, Source, SourceRecord
from mapping.runtime import set_threads, torch_threads
from mapping.team import AgentSnapshot, ChannelConfig, RoundPlan, Team, TeamConfig

Schedule = Callable[[Team, list[AgentSnapshot]], RoundPlan]
"""Who sends what to whom in the team's next round (``team.round_index``), from what each agent knows:
its snapshot (``Team.snapshots``) and its own fields (e.g. ``Team.column_maps``)."""

METRICS_NOTE = ("Per-agent metrics: each agent's own map against the whole ground truth; mean = their average "
                "(as the paper). {culling} acc_cm_unculled scores the whole reconstruction (and *_nice "
                "NICE-SLAM-culled, when asked). bytes_* count the serialised parameter and ray messages (and the "
                "clouds inside them). fleet_s: per round, the slowest agent's local phase + the exchange + the "
                "slowest consistency phase, summed.")


NOT_EVALUATED_NOTE = ("Not evaluated (--no-evaluation): only what the rounds cost. The same command without it "
                      "resumes after the last round and scores the maps.")


@dataclass(frozen=True)
class RunConfig:
    """How a run goes: the tree's job settings as they are, and what the run resolved around them."""

    job: RunSettings
    """Output folder, device, threads, workers (resolved: a number), processes, learner, checkpoints, scoring."""
    team: TeamConfig
    """The team the run starts (``openmulti_env.experiment.resolved_team``)."""
    channel: ChannelConfig = field(default_factory=ChannelConfig)
    seed: int = 0
    """Drives network initialisation, ray sampling and channel draws (and the scoring's samples)."""
    title: str = ""
    """Title of the pictures (e.g. the scene and policy)."""


@dataclass
class RunResult:
    """A finished run: per-agent scores, their mean, the team's semantics, what the rounds cost."""

    agents: dict[str, dict]
    """Per agent: acc_cm, comp_cm, comp_ratio, f_miou, f_macc (+ other cullings), instances."""
    mean: dict
    team: dict
    """F-mIoU / F-mAcc of all agents' maps together, per class."""
    bytes_sent_total: int
    bytes_per_round: list[int]
    bytes_per_link_total: list[list[int]]
    bytes_per_round_per_agent_mean: float
    messages: dict[str, int]
    fleet_s: float
    compute_s: dict[str, float]
    rounds: int
    wall_s: float
    config: dict
    """The run's settings (``openmulti run``: the whole configuration tree, as in ``config.yaml``)."""
    resolved: dict
    """What the run resolved from them: the team it started (a global map's frame, a recording's mapper) and
    values that follow from the settings (e.g. the error rates)."""
    notes: str
    extra: dict = field(default_factory=dict)
    """Source-specific fields (e.g. ``map``, ``ground_truth``, ``masks``)."""
    evaluated: bool = True
    """False: the maps were not scored (``RunSettings.evaluate``); ``agents``, ``mean`` and ``team`` are empty."""

    def as_json(self) -> dict:
        """``metrics.json``."""
        data = asdict(self)
        extra = data.pop("extra")
        return {**data, **extra}


def run_team(source: Source, record: SourceRecord, config: RunConfig, schedule: Schedule,
             start: float | None = None) -> RunResult:
    """Map ``source`` with a team under ``schedule``, score every agent's map, write the outputs.

    ``start`` is the ``time.perf_counter()`` the run's wall time counts from (default: now)."""
    start = time.perf_counter() if start is None else start
    out = Path(config.job.out)
    # checkpoints must come from the same team settings too, defaults included: a run made before a
    # default changed is mapped again, not resumed into a mix of two versions
    identity = record.settings if record.identity is None else record.identity
    forget_stale_checkpoints(out, {**identity, "team": as_record(asdict(config.team))}, record.read_identity)
    team = Team(source.streams(), config.team, source.vocabulary(), seed=config.seed, channel=config.channel,
                device=config.job.device, workers=config.job.workers, processes=config.job.processes,
                learner=config.job.learner)
    try:
        reports = run_rounds(team, schedule, out / "checkpoints" / "team.pt", config)
    except BaseException:
        team.release()  # member processes too: a failed run leaves nothing holding CPUs
        raise
    finally:
        team.close()  # the worker threads (the team stays usable for evaluation)
    set_threads(config.job.threads)  # evaluation runs on this thread alone: give it every core again
    gt = source.ground_truth(config.seed) if config.job.evaluate else None
    try:
        scores = (evaluate_team(source, record, gt, team, config) if gt is not None
                  else {"agents": {}, "mean": {}, "team": {}})
    finally:
        team.release()  # member processes end once their maps are copied here
    note = METRICS_NOTE.format(culling=gt.culling_note) if gt is not None else NOT_EVALUATED_NOTE
    result = RunResult(**scores, **round_costs(team, reports), wall_s=time.perf_counter() - start,
                       config=record.settings,
                       resolved={"team": plain(asdict(config.team)), **record.described},
                       notes=" ".join(record.notes + [note]), extra=record.results, evaluated=config.job.evaluate)
    write_outputs(out, result, reports, config)
    return result


def run_rounds(team: Team, schedule: Schedule, checkpoint: Path, config: RunConfig) -> list[dict]:
    """Rounds until the streams end, resuming from ``checkpoint`` when it exists; per-round reports (JSON)."""
    reports: list[dict] = []
    if checkpoint.is_file():
        try:
            reports = team.load(checkpoint)["reports"]
            print(f"[openmulti] resumed the team after round {team.round_index} from {checkpoint}")
        except CheckpointError as exc:
            print(f"[openmulti] ignoring unusable checkpoint ({exc}); starting again")
    total = team.rounds_total() if config.job.max_rounds is None else min(config.job.max_rounds, team.rounds_total())
    every = config.job.checkpoint_every
    snapshots = team.snapshots()
    with tqdm(total=total, initial=team.round_index, desc="rounds", unit="round", disable=not config.job.progress) as bar:
        while not team.done and team.round_index < total:
            report = team.round(schedule(team, snapshots))
            snapshots = report.agents
            reports.append(report.as_dict())
            bar.set_postfix(MB=f"{sum(report.bytes_sent) / 1e6:.1f}", fleet_s=f"{report.fleet_s:.1f}",
                            instances=sum(s.instances for s in snapshots))
            bar.update(1)
            last = team.round_index == total
            if (every and (team.round_index % every == 0 or last)) or (last and not config.job.evaluate):
                # a run that is not evaluated keeps its last round whatever checkpoint_every says: scoring resumes it
                team.save(checkpoint, extra={"reports": reports})
    return reports


class TakingTurns:
    """An encoder whose calls take turns: members scored on threads share the run's one text (and image) encoder,
    whose caches are not made for concurrent writers."""

    def __init__(self, encoder):
        self.encoder, self.lock = encoder, threading.Lock()

    @classmethod
    def wrap(cls, encoder):
        return None if encoder is None else cls(encoder)

    def __getattr__(self, name: str):
        attr = getattr(self.encoder, name)
        if not callable(attr):
            return attr

        def in_turn(*args, **kwargs):
            with self.lock:
                return attr(*args, **kwargs)
        return in_turn


def evaluate_team(source: Source, record: SourceRecord, gt: GroundTruth, team: Team, config: RunConfig) -> dict:
    """Mesh, cull and score every agent's own map against ``gt``; the team map's semantics; code books;
    pictures."""
    out, seed = Path(config.job.out), config.seed
    views = source.camera_views(config.team.mapping.keyframe_every) if config.job.three_cullings else None
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    gt.mesh.export(out / "meshes" / gt.file_name)
    per_agent, maps = {}, []
    reference = SampledSurface.of(gt.mesh, seed=seed)  # every agent is scored against the same points
    members = team.local_members()
    # each member's inputs are read here, in turn (the source's caches are not shared across threads); the scoring
    # itself (meshing, culling, scores: one member's state each) runs on the run's worker threads, the torch threads
    # split among them (every core each would run workers x cores threads); what overlaps is mostly the NumPy and
    # Python around the networks, which in turn left the other cores idle
    inputs = {m.name: (source.agent_frames(m.index, DEPTH_CHECK_EVERY), heldout_frames(source, m.index, config.team))
              for m in members}
    text_encoder, image_encoder = TakingTurns.wrap(source.text_encoder), TakingTurns.wrap(source.image_encoder)

    def score(member):
        frames, heldout = inputs[member.name]
        return score_member(member, gt, views, seed, out, text_encoder, image_encoder, record.caption, frames=frames,
                            heldout=heldout, reference=reference, viewpoint_stride=config.job.culling_viewpoint_stride)

    side_by_side = max(1, min(config.job.workers, len(members)))
    with torch_threads(config.job.threads, workers=side_by_side), \
            ThreadPoolExecutor(side_by_side, thread_name_prefix="scoring") as pool:
        scored = list(tqdm(pool.map(score, members), total=len(members), desc="evaluating", unit="agent",
                           disable=not config.job.progress))
    for member, (metrics, own) in zip(members, scored):
        per_agent[member.name] = metrics
        maps.append(own)
        if config.job.plots:  # matplotlib is not thread-safe: the pictures in turn
            save_rendered_views(out / "plots" / f"rendered_views_{member.name}.png", source, member,
                                f"{source.name} {member.name}: sensor vs map", own.mesh)
    union = team_semantics(maps, gt.semantic, out)
    if config.job.plots:
        from mapping.pipeline.plots import save_reconstruction_views, save_semantic_classes  # noqa: PLC0415

        save_reconstruction_views(out / "plots" / "reconstruction_top_down.png", gt.mesh, [m.scored for m in maps],
                                  gt.reference_note, seed)
        if union is not None:
            save_semantic_classes(out / "plots" / "semantic_per_class.png", union, f"{source.name}: all agents' maps")
    return {"agents": per_agent, "mean": mean_metrics(per_agent),
            "team": {"f_miou": None if union is None else union.f_miou,
                     "f_macc": None if union is None else union.f_macc,
                     "per_class": [] if union is None else union.as_dict()["per_class"]}}


def round_costs(team: Team, reports: list[dict]) -> dict:
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


def write_outputs(out: Path, result: RunResult, reports: list[dict], config: RunConfig) -> None:
    """``rounds.json``, ``metrics.json`` and (with ``plots``) the bytes-per-round picture."""
    write_json_atomic(out / "rounds.json", {"rounds": reports})
    write_json_atomic(out / "metrics.json", result.as_json())
    if config.job.plots:
        from mapping.pipeline.plots import save_round_bytes  # noqa: PLC0415

        save_round_bytes(out / "plots" / "bytes_per_round.png", reports, config.title)


def heldout_frames(source: Source, agent: int, team: TeamConfig) -> list:
    """The agent's frames its map never saw (``TeamConfig.holdout_every``; none without it)."""
    k = team.holdout_every
    return [] if k is None else source.agent_frames(agent, k, offset=k - 1)


def save_rendered_views(path: Path, source: Source, member, title: str, mesh=None) -> None:
    """A few of the agent's frames: the sensor's RGB and depth beside the map rendered from the same pose,
    and where its ``mesh`` is right, off or missing against the sensor depth."""
    from mapping.evaluate.depth_check import depth_classes  # noqa: PLC0415
    from mapping.pipeline.plots import save_view_comparison  # noqa: PLC0415

    frames, stride = source.sensor_views(member.index)
    views = []
    for frame in frames:
        rendered = member.mapper.render_view(frame.pose, frame.intrinsics, stride=stride)
        views.append((frame, rendered.colour.cpu().numpy(), rendered.depth.cpu().numpy(),
                      None if mesh is None else depth_classes(mesh, frame, stride)))
    save_view_comparison(path, views, stride, title)
