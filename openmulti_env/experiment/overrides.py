"""Overrides of a configuration tree: dotted paths (``team.exchange.float16``), the short spellings the env's
keywords and the older command line use (``float16``), and strict checks of every value against its field's
type, so that a typo names the nearest valid keys and a wrong value names the field and what it takes."""

from __future__ import annotations

import dataclasses
import difflib
import types
import typing
from functools import lru_cache
from typing import Any, Mapping

ALIASES: dict[str, str] = {
    # the world
    "agents": "world.num_agents",
    "frames_per_agent": "world.path.frames_per_agent", "planning_points": "world.path.planning_points",
    "image_width": "world.sensor.width", "image_height": "world.sensor.height",
    "culling_edge_m": "world.culling_edge_m",
    # the front end
    "segmentation_errors": "perception.segmentation_errors", "text_encoder": "perception.text_encoder",
    "clip_checkpoint": "perception.clip_checkpoint", "segmenter": "perception.segmenter",
    # the team
    "frames_per_round": "team.frames_per_round", "alignment": "team.alignment", "global_map": "team.global_map",
    "shared_global_init": "team.shared_global_init", "holdout_every": "team.holdout_every",
    "keyframe_every": "team.mapping.keyframe_every", "iterations_per_keyframe": "team.mapping.iterations_per_keyframe",
    "rays_per_object": "team.mapping.rays_per_object", "rays_per_structure": "team.mapping.rays_per_structure",
    "refit_steps": "team.mapping.refit_steps",
    "consistency": "team.consistency.algorithm", "consistency_iterations": "team.consistency.iterations",
    "rays_per_pose": "team.consistency.rays_per_pose", "cross_rendering": "team.consistency.cross_rendering",
    "missing_edges": "team.consistency.missing_edges",
    "float16": "team.exchange.float16", "changed_only": "team.exchange.changed_only",
    "share_point_clouds": "team.exchange.point_clouds",
    # the global baselines
    "global_width": "global_map.width", "global_encoding_scale": "global_map.encoding_scale",
    "global_form": "global_map.form", "sdf": "global_map.sdf",
    # the links
    "success_probability": "channel.success_probability", "comm_budget_mb": "channel.budget_mb",
    "link_range_m": "channel.link_range_m", "link_success": "channel.link_success", "link_mb_per_round": "channel.link_mb_per_round",
    # the env
    "reward": "env.reward", "comm_cost_per_mb": "env.comm_cost_per_mb", "reward_baseline": "env.reward_baseline",
    "comm_cost_of_always": "env.comm_cost_of_always", "action_form": "env.action_form", "episode": "env.episode",
    "recordings": "env.recordings",
    "instance_slots": "env.instance_slots", "budget_penalty": "env.budget_penalty",
    "probe_points": "env.probe_points", "map_size": "env.map_size", "horizon": "env.horizon",
    "frame_cache_mb": "env.frame_cache_mb", "cache_dir": "env.cache_dir",
    "cache_max_mb": "env.cache_max_mb",
    # the job
    "policy": "run.policy", "out": "run.out", "device": "run.device", "threads": "run.threads",
    "workers": "run.workers", "processes": "run.processes", "learner": "run.learner", "checkpoint_every": "run.checkpoint_every",
    "max_rounds": "run.max_rounds", "three_cullings": "run.three_cullings", "culling_viewpoint_stride": "run.culling_viewpoint_stride", "plots": "run.plots",
    "evaluate": "run.evaluate", "progress": "run.progress",
    # a data set
    "data": "data.path", "kind": "data.kind", "gt_mesh": "data.gt_mesh", "frames": "data.frames",
    "intrinsics": "data.intrinsics", "depth_scale": "data.depth_scale", "recording_mapper": "data.recording_mapper",
}
"""The one short spelling of a field that has one: the env's keyword (``parallel_env(rays_per_object=100)``) and,
for those ``openmulti run`` lists (``runs.cli.RUN_SHORT``), its short option. Every field is also its dotted
path (``--team.mapping.rays_per_object``, ``parallel_env(team__mapping__rays_per_object=100)``)."""

OLD_SPELLINGS: dict[str, str] = {"num_agents": "world.num_agents", "max_cycles": "env.horizon",
                                 "agent_workers": "run.workers", "agent_processes": "run.processes"}
"""Second spellings older versions accepted and wrote in their flat records: read only by the reader of those
records (``files.py``). ``parallel_env``'s own ``num_agents`` and ``max_cycles`` are PettingZoo's arguments."""

ALIGNMENT_WORDS = {"paper": True, "none": False}
"""``alignment`` as the older records and command line spell it (``team.alignment`` is a bool)."""


class ConfigError(ValueError):
    """A configuration that cannot be read: names the key or field and what it takes."""


class UnknownOptionError(ConfigError, TypeError):
    """A key that names no field (a TypeError too, as an unknown keyword argument is in Python)."""


def leaf_paths(cls: type, prefix: str = "") -> dict[str, Any]:
    """Every settable field of the tree under ``cls``: dotted path -> type (nested dataclasses are
    descended into; a dataclass that may be None, such as ``team.mapping.structure_sdf``, is one leaf)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        kind = field_types(cls)[f.name]
        path = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(kind):
            out.update(leaf_paths(kind, path + "."))
        else:
            out[path] = kind
    return out


@lru_cache(maxsize=None)
def field_types(cls: type) -> dict[str, Any]:
    """``cls``'s field types, resolved (the modules use ``from __future__ import annotations``)."""
    return typing.get_type_hints(cls)


def node_paths(cls: type, prefix: str = "") -> set[str]:
    """The dotted paths of the nested dataclasses under ``cls`` (a whole node may be given as a mapping)."""
    out = set()
    for f in dataclasses.fields(cls):
        kind = field_types(cls)[f.name]
        if dataclasses.is_dataclass(kind):
            out.add(prefix + f.name)
            out |= node_paths(kind, prefix + f.name + ".")
    return out


def resolve_key(root: type, key: str) -> str:
    """The dotted path a key names (itself, or the path of a short spelling); ConfigError naming the
    nearest valid keys when it names nothing."""
    key = key.replace("-", "_")
    leaves, nodes = set(leaf_paths(root)), node_paths(root)
    if key in leaves:
        return key
    if key in ALIASES:  # before the nodes: ``data`` is the data set's path (a whole node is ``data`` given a mapping)
        return ALIASES[key]
    if key in nodes:
        return key
    known = leaves | nodes
    near = difflib.get_close_matches(key, sorted(known | set(ALIASES)), n=3, cutoff=0.6)
    hint = f"; did you mean {', '.join(near)}?" if near else "; `openmulti run --help` lists every option"
    raise UnknownOptionError(f"unknown option {key!r}{hint}")


def apply_overrides(tree, overrides: Mapping[str, Any]):
    """``tree`` with each ``path: value`` (dotted path or short spelling) set, every value checked against
    its field's type (ConfigError naming the field otherwise)."""
    root = type(tree)
    for key, value in overrides.items():
        path = resolve_key(root, key)
        if path == "team.alignment" and isinstance(value, str):
            if value not in ALIGNMENT_WORDS:
                raise ConfigError(f"unknown alignment {value!r}; choose one of {tuple(ALIGNMENT_WORDS)} (the team has "
                                  "no ground-truth 'oracle' alignment; it is in python -m studies.alignment)")
            value = ALIGNMENT_WORDS[value]
        tree = _set(tree, path.split("."), value, path)
    return tree


def _set(node, parts: list[str], value, path: str):
    name = parts[0]
    names = {f.name for f in dataclasses.fields(node)}
    if name not in names:  # resolve_key checked the path; a node given whole may still hold a typo
        raise ConfigError(f"unknown option {path!r}")
    kind = field_types(type(node))[name]
    if len(parts) > 1:
        return dataclasses.replace(node, **{name: _set(getattr(node, name), parts[1:], value, path)})
    return _replace_checked(node, name, checked_value(value, kind, path))


def _replace_checked(node, name: str, value):
    """``replace`` with a dataclass's own checks (``__post_init__``) reported as this option's error."""
    try:
        return dataclasses.replace(node, **{name: value})
    except (TypeError, ValueError) as exc:
        raise ConfigError(str(exc)) from None


def checked_value(value, kind, path: str):
    """``value`` as a value of ``kind`` (ints as floats where a float is wanted, lists as tuples, mappings as
    dataclasses); ConfigError naming ``path`` and what it takes otherwise."""
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for option in (a for a in args if a is not type(None)):
            try:
                return checked_value(value, option, path)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(f"{path} takes {type_name(kind)}, got {value!r}")
    if dataclasses.is_dataclass(kind):
        if isinstance(value, kind):
            return value
        if not isinstance(value, Mapping):
            raise ConfigError(f"{path} takes a mapping of {kind.__name__}'s fields, got {value!r}")
        return from_mapping(kind, value, path)
    if kind is bool:
        if isinstance(value, bool):
            return value
    elif kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():  # 1e5 in YAML or on the command line is a float
            return int(value)
    elif kind is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif kind is str:
        if isinstance(value, str):
            return value
    elif origin is tuple:
        if isinstance(value, (list, tuple)):
            if len(args) == 2 and args[1] is Ellipsis:
                return tuple(checked_value(v, args[0], path) for v in value)
            if len(value) == len(args):
                return tuple(checked_value(v, a, path) for v, a in zip(value, args))
    elif kind is Any:
        return value
    raise ConfigError(f"{path} takes {type_name(kind)}, got {value!r}")


def from_mapping(cls: type, data: Mapping, prefix: str = ""):
    """A ``cls`` from a mapping of its fields (nested mappings for nested dataclasses); ConfigError naming an
    unknown field (and the nearest ones) or a wrong value."""
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = [k for k in data if k not in names]
    if unknown:
        near = difflib.get_close_matches(unknown[0], names, n=3, cutoff=0.6)
        where = f"{prefix}.{unknown[0]}" if prefix else unknown[0]
        raise ConfigError(f"unknown field {where!r}" + (f"; did you mean {', '.join(near)}?" if near else
                                                          f"; {cls.__name__} has {', '.join(names)}"))
    types_ = field_types(cls)
    values = {k: checked_value(v, types_[k], f"{prefix}.{k}" if prefix else k) for k, v in data.items()}
    try:
        return cls(**values)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{prefix or cls.__name__}: {exc}") from None


def type_name(kind) -> str:
    """A type as a person reads it (``int or None``, ``a list of float``)."""
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin in (typing.Union, types.UnionType):
        return " or ".join("None" if a is type(None) else type_name(a) for a in args)
    if origin is tuple:
        return f"a list of {type_name(args[0])}" if args and args[-1] is Ellipsis else f"a list of {len(args)} values"
    if dataclasses.is_dataclass(kind):
        return f"a mapping of {kind.__name__}'s fields"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(kind, str(kind))
