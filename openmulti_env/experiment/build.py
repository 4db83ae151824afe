"""A tree as a preset plus overrides, checked whole (``experiment``), and what a run resolves from it at run
time (``resolved_team``): the one place every entry point builds its settings."""

from __future__ import annotations

import math
import typing
from dataclasses import replace
from typing import Any, Mapping

from mapping.model.agent_config import MappingConfig
from mapping.perception.geometric_segmenter import SEGMENTER_SETTINGS
from mapping.team import TeamConfig
from mapping.team.consistency import CONSISTENCY_ALGORITHMS
from mapping.team.global_map import GLOBAL_FORMS, MACIM_RHO
from mapping.team.team import LEARNERS
from openmulti_env.experiment.overrides import ConfigError, apply_overrides, leaf_paths, resolve_key
from openmulti_env.experiment.tree import (DATA_KINDS, PROCESS_MODES, REWARD_BASELINES, REWARD_MODES, TEXT_ENCODERS, Experiment)
from openmulti_env.world.world import MAX_AGENTS

MINIMUMS = ("team.min_keyframes", "team.min_local_steps")
"""Team fields that follow ``world.path.frames_per_agent`` and the mapping unless set explicitly."""


def experiment(preset: str = "fast", overrides: Mapping[str, Any] | None = None, base: Experiment | None = None,
               **more) -> Experiment:
    """The tree of ``preset`` (or ``base``, e.g. a recorded tree) with ``overrides`` and ``more`` applied
    (dotted paths or short spellings, ``openmulti_env.experiment.overrides.ALIASES``), checked whole.

    ``None`` values of short spellings keep the preset's value unless None means something for that field
    (``horizon``, ``comm_budget_mb``, ...): the env's keywords default to None."""
    from openmulti_env.presets import get_preset  # noqa: PLC0415  (the presets are trees of this package)

    tree = get_preset(preset) if base is None else base
    given = {k: v for k, v in {**(overrides or {}), **more}.items() if v is not None or admits_none(k)}
    paths = {resolve_key(Experiment, k): k for k in given}
    tree = apply_overrides(tree, given)
    if not any(p in paths or p == "team" for p in MINIMUMS):
        tree = tree.with_team_minimums()  # the minimums follow the overridden path length and mapping
    if "channel.success_probability" not in paths and "channel" not in paths:
        success = policy_success_probability(tree.run.policy)
        if success is not None:
            tree = replace(tree, channel=replace(tree.channel, success_probability=success))
    return check(tree)


def device_problem(device: str) -> str | None:
    """Why ``device`` names no device a run can use ("auto", "cpu", "cuda", "cuda:N", "mps"), or None."""
    import torch  # noqa: PLC0415

    if device == "auto":
        return None
    try:
        kind = torch.device(device).type
    except (RuntimeError, TypeError, ValueError):
        return f"{device!r} is not a device; use 'auto', 'cpu', 'cuda' or 'cuda:N'"
    if kind not in ("cpu", "cuda", "mps"):
        return f"{device!r} is a {kind} device; runs use 'auto', 'cpu', 'cuda' or 'cuda:N'"
    return None


def admits_none(key: str) -> bool:
    """Whether the field a key names may be None (its None is a setting, not "keep the preset's")."""
    path = resolve_key(Experiment, key)
    kind = leaf_paths(Experiment).get(path)
    return kind is not None and type(None) in typing.get_args(kind)


def policy_success_probability(policy: str) -> float | None:
    """The link success rate a ``bernoulli:P`` policy names (None for the others: their links are perfect)."""
    from policies import parse_policy  # noqa: PLC0415

    success = parse_policy(policy).success_probability
    return success if success < 1.0 else None


def check(tree: Experiment) -> Experiment:
    """``tree``, or ConfigError naming the field and what it takes (checks across fields and of names)."""
    def need(ok: bool, message: str) -> None:
        if not ok:
            raise ConfigError(message)

    need(1 <= tree.world.num_agents <= MAX_AGENTS,
         f"world.num_agents must be between 1 and {MAX_AGENTS}, got {tree.world.num_agents}")
    need(tree.perception.text_encoder in TEXT_ENCODERS,
         f"perception.text_encoder must be one of {TEXT_ENCODERS}, got {tree.perception.text_encoder!r}")
    need(tree.perception.segmenter in SEGMENTER_SETTINGS,
         f"perception.segmenter must be one of {tuple(SEGMENTER_SETTINGS)}, got {tree.perception.segmenter!r}")
    need(tree.team.consistency.algorithm in CONSISTENCY_ALGORITHMS,
         f"team.consistency.algorithm must be one of {CONSISTENCY_ALGORITHMS}, got {tree.team.consistency.algorithm!r}")
    need(tree.global_map.form in GLOBAL_FORMS,
         f"global_map.form must be one of {GLOBAL_FORMS}, got {tree.global_map.form!r}")
    need(tree.team.shared_global_init or tree.team.global_map,
         "team.shared_global_init=False applies to a global map only (team.global_map=True)")
    need(tree.env.reward in REWARD_MODES, f"env.reward must be one of {REWARD_MODES}, got {tree.env.reward!r}")
    need(tree.env.horizon is None or tree.env.horizon >= 1,
         f"env.horizon (max_cycles) must be >= 1 or None, got {tree.env.horizon}")
    need(tree.env.map_size >= 8, f"env.map_size must be at least 8 pixels, got {tree.env.map_size}")
    need(tree.run.processes in PROCESS_MODES, f"run.processes must be None or 'ray', got {tree.run.processes!r}")
    need(tree.run.learner in LEARNERS, f"run.learner must be one of {LEARNERS}, got {tree.run.learner!r}")
    need(isinstance(tree.run.culling_viewpoint_stride, int) and tree.run.culling_viewpoint_stride >= 1,
         f"run.culling_viewpoint_stride must be a whole number >= 1 (1: every viewpoint), "
         f"got {tree.run.culling_viewpoint_stride!r}")
    need(not (tree.run.learner == "fleet" and tree.run.processes),
         "run.learner='fleet' batches agents in this process: not with run.processes")
    need(tree.run.workers is None or tree.run.workers >= 1, f"run.workers must be >= 1, got {tree.run.workers}")
    need(tree.run.checkpoint_every >= 0, f"run.checkpoint_every must be >= 0, got {tree.run.checkpoint_every}")
    need(tree.data.kind in DATA_KINDS, f"data.kind must be one of {DATA_KINDS}, got {tree.data.kind!r}")
    for path, value in (("world.path.frames_per_agent", tree.world.path.frames_per_agent),
                        ("team.frames_per_round", tree.team.frames_per_round),
                        ("team.mapping.keyframe_every", tree.team.mapping.keyframe_every),
                        ("team.consistency.rays_per_pose", tree.team.consistency.rays_per_pose),
                        ("env.probe_points", tree.env.probe_points)):
        need(value >= 1, f"{path} must be >= 1, got {value}")
    need(tree.env.reward_baseline in REWARD_BASELINES,
         f"env.reward_baseline must be one of {REWARD_BASELINES}, got {tree.env.reward_baseline!r}")
    need(tree.env.reward_baseline != "front" or tree.env.reward == "team",
         f"env.reward_baseline='front' prices the team's bytes on the team's front: it needs env.reward='team', "
         f"got {tree.env.reward!r}")
    for path, value in (("env.comm_cost_per_mb", tree.env.comm_cost_per_mb), ("env.comm_cost_of_always", tree.env.comm_cost_of_always),
                        ("env.budget_penalty", tree.env.budget_penalty)):
        need(math.isfinite(value) and value >= 0, f"{path} must be a finite number >= 0, got {value}")
    success = tree.channel.link_success
    need(success is None or len(success) == tree.num_agents,
         f"channel.link_success is {len(success or ())} x {len(success or ())}, the team has {tree.num_agents} agents")
    need(tree.env.action_form in ("entries", "round", "instances"),
         f"env.action_form must be one of ('entries', 'round', 'instances'), got {tree.env.action_form!r}")
    need(isinstance(tree.env.instance_slots, int) and 1 <= tree.env.instance_slots <= 256,
         f"env.instance_slots must be a whole number of slots per peer in 1..256, got {tree.env.instance_slots!r}")
    changed = tree.team.exchange.changed_only
    need(changed is None or (math.isfinite(changed) and changed >= 0),
         f"team.exchange.changed_only must be None or a finite number >= 0, got {changed}")
    need(tree.run.threads is None or tree.run.threads >= 1, f"run.threads must be >= 1 or None, got {tree.run.threads}")
    need(device_problem(tree.run.device) is None, f"run.device: {device_problem(tree.run.device)}")
    need(tree.channel.budget_mb is not None or not policy_needs_budget(tree.run.policy),
         "policy 'budget' needs a budget: --comm-budget-mb MB (channel.budget_mb, the megabytes each agent may send)")
    need(tree.channel.link_success is None or policy_success(tree.run.policy) >= 1.0,
         f"policy {tree.run.policy!r} sets one success probability for every link, channel.link_success one per "
         "link: give one of them (e.g. --policy always with --channel.link-success)")
    return tree


def policy_success(policy: str) -> float:
    from policies import parse_policy  # noqa: PLC0415

    return parse_policy(policy).success_probability


def policy_needs_budget(policy: str) -> bool:
    from policies import parse_policy  # noqa: PLC0415

    return parse_policy(policy).rule == "budget"


def resolved_team(tree: Experiment, mapping: MappingConfig | None = None) -> TeamConfig:
    """The team settings a run starts its team with: the tree's, with ``mapping`` in place of its mapper
    settings when the run resolves them (a global map's frame, a recording's mapper), the minimums following
    that mapping when they follow the tree's (``Experiment.with_team_minimums``), and MACIM's rho for the
    published global map."""
    team = tree.team
    if mapping is not None:
        follows = team == tree.with_team_minimums().team
        team = replace(team, mapping=mapping)
        if follows:
            team = replace(tree, team=team).with_team_minimums().team
    if team.global_map and tree.global_map.form == "published":
        team = replace(team, consistency=replace(team.consistency, rho=MACIM_RHO))
    return team
