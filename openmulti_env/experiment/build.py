"""A tree as a preset plus overrides, checked whole (``experiment``), and what a run resolves from it at run
time (``resolved_team``): the one place every entry point builds its settings."""

from __future__ import annotations

import typing
from dataclasses import replace
from typing import Any, Mapping

from mapping.config_fields import range_problem
from mapping.model.agent_config import MappingConfig
from mapping.perception.geometric_segmenter import SEGMENTER_SETTINGS
from mapping.team import TeamConfig
from mapping.team.consistency import CONSISTENCY_ALGORITHMS
from mapping.team.global_map import GLOBAL_FORMS, MACIM_RHO
from mapping.team.message_checks import MessageRules
from mapping.team.team import LEARNERS
from openmulti_env.experiment.memory import memory_problem
from openmulti_env.experiment.overrides import ConfigError, apply_overrides, leaf_paths, resolve_key
from openmulti_env.experiment.tree import (DATA_KINDS, DEFAULT_PRESETS, PROCESS_MODES, REWARD_BASELINES, REWARD_MODES,
                                           TEXT_ENCODERS, Experiment)

MINIMUMS = ("team.min_keyframes", "team.min_local_steps")
"""Team fields that follow ``world.path.frames_per_agent`` and the mapping unless set explicitly."""


def experiment(preset: str = DEFAULT_PRESETS["run"], overrides: Mapping[str, Any] | None = None, base: Experiment | None = None,
               **more) -> Experiment:
    """The tree of ``preset`` (or ``base``, e.g. a recorded tree) with ``overrides`` and ``more`` applied
    (dotted paths or short spellings, ``openmulti_env.experiment.overrides.ALIASES``), checked whole.

    ``None`` values of short spellings keep the preset's value unless None means something for that field
    (``horizon``, ``comm_budget_mb``, ...): the env's keywords default to None."""
    from openmulti_env.experiment.presets import get_preset  # noqa: PLC0415  (the presets are trees of this package)

    tree = get_preset(preset) if base is None else base
    given = {k: v for k, v in {**(overrides or {}), **more}.items() if v is not None or admits_none(k)}
    paths = {resolve_key(Experiment, k): k for k in given}
    tree = apply_overrides(tree, given)
    in_range = range_problem(tree)
    if in_range:  # before anything below divides by a setting (keyframe_every 0)
        raise ConfigError(in_range)
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
    """``tree``, or ConfigError naming the field and what it takes: every number in its field's range
    (``mapping.config_fields``), the names each field knows, the checks across fields and the estimated size of
    the largest allocations (``openmulti_env.experiment.memory``), all before anything is built."""
    for problem in (range_problem, preset_problem, name_problem, cross_field_problem, memory_problem):
        message = problem(tree)
        if message:
            raise ConfigError(message)
    return tree


def preset_problem(tree: Experiment) -> str | None:
    """Why ``tree.preset`` names no preset, or None."""
    from openmulti_env.experiment.presets import PRESET_NAMES  # noqa: PLC0415  (the presets are trees of this package)

    if tree.preset not in PRESET_NAMES:
        return f"preset must be one of {PRESET_NAMES}, got {tree.preset!r}"
    return None


def name_problem(tree: Experiment) -> str | None:
    """The first field that names something unknown (an encoder, a form, a device), or None."""
    names = (("perception.text_encoder", tree.perception.text_encoder, TEXT_ENCODERS),
             ("perception.segmenter", tree.perception.segmenter, tuple(SEGMENTER_SETTINGS)),
             ("team.consistency.algorithm", tree.team.consistency.algorithm, CONSISTENCY_ALGORITHMS),
             ("global_map.form", tree.global_map.form, GLOBAL_FORMS),
             ("env.reward", tree.env.reward, REWARD_MODES),
             ("env.reward_baseline", tree.env.reward_baseline, REWARD_BASELINES),
             ("env.action_form", tree.env.action_form, ("entries", "round", "instances")),
             ("env.episode", tree.env.episode, ("real", "recorded")),
             ("run.learner", tree.run.learner, LEARNERS),
             ("data.kind", tree.data.kind, DATA_KINDS))
    for path, value, known in names:
        if value not in known:
            return f"{path} must be one of {known}, got {value!r}"
    if tree.run.processes not in PROCESS_MODES:
        return f"run.processes must be None or 'ray', got {tree.run.processes!r}"
    device = device_problem(tree.run.device)
    return f"run.device: {device}" if device else None


def cross_field_problem(tree: Experiment) -> str | None:
    """The first rule between fields ``tree`` breaks, or None."""
    sensor, sampler, consistency = tree.world.sensor, tree.team.mapping.sampler, tree.team.consistency
    success = tree.channel.link_success
    rays = consistency.rays_per_pose * consistency.poses_per_message
    rules = (
        (tree.team.shared_global_init or tree.team.global_map,
         "team.shared_global_init=False applies to a global map only (team.global_map=True)"),
        (not (tree.run.learner == "fleet" and tree.run.processes),
         "run.learner='fleet' batches agents in this process: not with run.processes"),
        (tree.env.reward_baseline != "front" or tree.env.reward == "team",
         f"env.reward_baseline='front' prices the team's bytes on the team's front: it needs env.reward='team', "
         f"got {tree.env.reward!r}"),
        (success is None or len(success) == tree.num_agents,
         f"channel.link_success is {len(success or ())} x {len(success or ())}, the team has {tree.num_agents} agents"),
        (sensor.min_depth_m < sensor.max_depth_m,
         f"world.sensor.min_depth_m ({sensor.min_depth_m}) must be below world.sensor.max_depth_m ({sensor.max_depth_m})"),
        (sampler.near_m < sampler.far_m,
         f"team.mapping.sampler.near_m ({sampler.near_m}) must be below team.mapping.sampler.far_m ({sampler.far_m})"),
        (sampler.n_stratified + sampler.n_surface >= 1,
         "team.mapping.sampler needs at least one sample per ray (n_stratified + n_surface >= 1)"),
        (rays <= MessageRules.max_rays,
         f"team.consistency.rays_per_pose x poses_per_message is {rays} rays a message, more than the "
         f"{MessageRules.max_rays} a receiver renders (mapping.team.message_checks.MessageRules.max_rays)"),
    )
    return next((message for ok, message in rules if not ok), None) or policy_problem(tree)


def policy_problem(tree: Experiment) -> str | None:
    """What the policy needs of the links that the tree does not give (a budget; one success rate), or None."""
    if tree.channel.budget_mb is None and policy_needs_budget(tree.run.policy):
        return "policy 'budget' needs a budget: --comm-budget-mb MB (channel.budget_mb, the megabytes each agent may send)"
    if tree.channel.link_success is not None and policy_success(tree.run.policy) < 1.0:
        return (f"policy {tree.run.policy!r} sets one success probability for every link, channel.link_success one "
                "per link: give one of them (e.g. --policy always with --channel.link-success)")
    return None


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
