"""A tree on disk: ``OUT/config.yaml`` (or ``.json``) written whole by every run, read back by
``openmulti run --config``, and the one place the records of older versions are read (their flat settings
dicts in ``checkpoints/run_settings.json`` and ``metrics.json``'s ``config``)."""

from __future__ import annotations

import difflib
import os
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import yaml

from mapping.config_fields import range_problem
from mapping.pipeline.records import as_record, missing_paths, neutral_default_paths
from mapping.safe_parse import ParseError, load_data
from openmulti_env.experiment.overrides import OLD_SPELLINGS, ConfigError, apply_overrides, from_mapping, leaf_paths, node_paths
from openmulti_env.experiment.tree import Experiment

FORMAT = "openmulti.experiment"
"""The ``format`` key of a written tree."""
VERSION = 1
"""The version of the tree's layout this code writes and reads; a file of another is refused."""
CONFIG_NAME = "config.yaml"

LEGACY_SOURCE_KEYS = ("kind", "scene", "frames_per_agent")
"""Keys a data-set source added to the flat records of version 0 (what it found on disk, not settings)."""
LEGACY_DROPPED = ("team", "three_cullings", "data_kind")
"""Keys of the version-0 records that are no option of the tree (the team is compared resolved, the
cullings decide no map)."""


def tree_record(tree: Experiment) -> dict:
    """The tree as plain JSON/YAML data, with its format and version."""
    return {"format": FORMAT, "version": VERSION, **as_record(asdict(tree))}


def write_config(tree: Experiment, out: Path) -> Path:
    """``out/config.yaml``, atomically (a crash never leaves half a file)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / CONFIG_NAME
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("# openmulti run --config " + str(path) + " --out NEW repeats this run\n"
                   + yaml.safe_dump(tree_record(tree), sort_keys=False, default_flow_style=None, width=110))
    os.replace(tmp, path)
    return path


def read_config(path: str | Path) -> Experiment:
    """The tree in a ``config.yaml`` / ``.json`` (or a run's ``metrics.json``, whose ``config`` it takes), every
    number in its field's range; ConfigError saying why it cannot be read (the file is read by
    ``mapping.safe_parse``: bounded in size and nesting, no duplicated keys, ``1e12`` a number)."""
    if not str(path).strip():
        raise ConfigError("--config names no file (an empty path); give a run's config.yaml or leave --config out")
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file {path} does not exist")
    try:
        data = load_data(path)
    except (OSError, ParseError) as exc:
        raise ConfigError(f"config file {path} cannot be read: {exc}") from None
    if isinstance(data, dict) and "config" in data and "mean" in data:  # a metrics.json
        data = data["config"]
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path} holds {type(data).__name__}, not a mapping of settings")
    try:
        return experiment_from_record(data)
    except ConfigError as exc:
        raise ConfigError(f"config file {path}: {exc}") from None


def experiment_from_record(record: dict) -> Experiment:
    """A tree from a written record: this version's (``tree_record``), or a version-0 flat settings dict
    (``openmulti run`` before the tree: ``scene``/``data``, ``agents``, ``policy``, ``preset``, ``seed``,
    ``alignment`` ``"paper"``/``"none"``, ``comm_budget_mb``, ...), read through the short spellings."""
    if "format" in record or "version" in record:
        if record.get("format") != FORMAT:
            raise ConfigError(f"not an experiment record (format {record.get('format')!r}, expected {FORMAT!r})")
        if record.get("version") != VERSION:
            raise ConfigError(f"written by another version of openmulti (layout version {record.get('version')!r}); "
                              f"this one reads version {VERSION}")
        return _from_version1(record)
    return _from_version0(record)


def _from_version1(record: dict) -> Experiment:
    """A record of this version as a tree: it must hold settings and name a known preset; every number is
    checked against its field's range (what needs the whole tree is checked when it is built)."""
    from openmulti_env.experiment.presets import PRESET_NAMES  # noqa: PLC0415  (the presets are trees of this package)

    settings = {k: v for k, v in record.items() if k not in ("format", "version")}
    if not settings:
        raise ConfigError("holds only its header (format and version), no settings: write the tree below it (a run "
                          "writes OUT/config.yaml whole)")
    if settings.get("preset") not in PRESET_NAMES:
        raise ConfigError(f"preset must be one of {PRESET_NAMES}, got {settings.get('preset')!r} (a record names the "
                          "preset its tree started from)")
    from openmulti_env.experiment.presets import get_preset  # noqa: PLC0415

    # on the named preset, so a hand-written file that leaves settings out gets its preset's, not Experiment()'s
    tree = apply_overrides(get_preset(settings["preset"]), record_leaves(settings))
    problem = range_problem(tree)
    if problem:
        raise ConfigError(problem)
    return tree


def record_leaves(settings: dict, prefix: str = "") -> dict[str, Any]:
    """A written tree's nested mappings as ``dotted.path: value`` of its leaves (``overrides.leaf_paths``; a node
    that may be None, such as ``team.mapping.structure_sdf``, is one leaf); ConfigError naming a key that names
    no field, and the nearest ones (a file spells every field by its path; no short spellings)."""
    leaves, nodes = leaf_paths(Experiment), node_paths(Experiment)
    out: dict[str, Any] = {}
    for key, value in settings.items():
        path = prefix + str(key)
        if path in leaves:
            out[path] = value
        elif path in nodes and isinstance(value, dict):
            out.update(record_leaves(value, path + "."))
        else:
            near = difflib.get_close_matches(path, sorted(set(leaves) | nodes), n=3, cutoff=0.6)
            raise ConfigError(f"unknown field {path!r}" + (f"; did you mean {', '.join(near)}?" if near else ""))
    return out


def _from_version0(record: dict) -> Experiment:
    """A flat settings dict of version 0 as a tree (see ``experiment_from_record``)."""
    from openmulti_env.experiment.build import experiment  # noqa: PLC0415

    if "preset" not in record or not ({"scene", "data"} & set(record)):
        raise ConfigError("not an experiment record: it has neither a format nor the flat settings of an older run "
                          "(preset and scene or data)")
    flat = {OLD_SPELLINGS.get(k, k): v for k, v in record.items() if k not in LEGACY_DROPPED and k != "preset"}
    if "data" in flat:
        for key in LEGACY_SOURCE_KEYS:
            flat.pop(key, None)
    if flat.get("global_form") == "published":
        flat.pop("global_width", None)  # version 0 recorded the SDF's width there; the tree reads sdf.width
    return experiment(record["preset"], flat)


def recorded_num_agents(config: dict) -> int:
    """The team size a ``metrics.json``'s ``config`` records, whichever version wrote it."""
    return int(config["world"]["num_agents"] if "world" in config else config["agents"])


def source_facts(record: dict) -> dict:
    """What a version-0 data-set record held of its source (detected layout, name, frames per agent)."""
    return {k: record[k] for k in LEGACY_SOURCE_KEYS if k in record} if "data" in record else {}


def maps_identity(tree: Experiment) -> dict:
    """What decides a run's maps (its checkpoints are kept only under the same): the tree without the job's
    settings (threads, output, progress, ...) but the policy, without the env's, and without the team (the run
    compares the team it resolved)."""
    record = as_record(asdict(tree))
    for key in ("env", "team", "format", "version"):
        record.pop(key, None)
    record["run"] = {"policy": tree.run.policy}
    if tree.data.path is not None:
        record["data"]["path"] = str(Path(tree.data.path).resolve())
    return record


def checkpoint_identity(tree: Experiment, source: dict[str, Any]) -> dict:
    """The record a run's checkpoints are made under, besides the team it resolved (the pipeline adds it as
    ``team``): ``maps_identity`` and what the source found on disk."""
    return {"format": FORMAT, "version": VERSION, "experiment": maps_identity(tree), "source": source}


def read_checkpoint_identity(record: dict) -> dict | None:
    """A record of ``checkpoints/run_settings.json`` as ``checkpoint_identity`` gives it, whichever version
    wrote it (None when it cannot be read: the checkpoints are then not trusted)."""
    if record.get("format") == FORMAT:
        return _with_neutral_defaults(record)
    try:
        tree = _from_version0(record)
    except (ConfigError, ValueError):
        return None
    if "team" not in record:
        return None
    tree = replace(tree, run=replace(tree.run, policy=record.get("policy", tree.run.policy)))
    return {**checkpoint_identity(tree, source_facts(record)), "team": record["team"]}


def _with_neutral_defaults(record: dict) -> dict | None:
    """A record of this version written before some ``neutral_default`` settings existed, with them filled in
    at their defaults (the behaviour from before they existed); None when it lacks any other setting."""
    experiment_record = record.get("experiment")
    if (record.get("version") != VERSION or not isinstance(experiment_record, dict)
            or set(record) != {"format", "version", "experiment", "source", "team"}):
        return None
    try:
        tree = from_mapping(Experiment, experiment_record)
    except ConfigError:
        return None
    team = _team_with_neutral_defaults(record["team"])
    if team is None:
        return None
    filled = {**checkpoint_identity(tree, record["source"]), "team": team}
    lacking = missing_paths(experiment_record, filled["experiment"])
    if lacking is None or not lacking <= neutral_default_paths(tree):
        return None
    return filled


def _team_with_neutral_defaults(team_record) -> dict | None:
    """A checkpoint's resolved team written before some ``neutral_default`` team settings existed (such as
    ``exchange.codec``), with them at their defaults; as written when it lacks nothing; None when it lacks
    another setting or does not read as a team."""
    from mapping.team import TeamConfig  # noqa: PLC0415

    if not isinstance(team_record, dict):
        return None
    try:
        team = from_mapping(TeamConfig, team_record)
    except ConfigError:
        return None
    filled = as_record(asdict(team))
    lacking = missing_paths(team_record, filled)
    if lacking is None or not lacking <= neutral_default_paths(team):
        return None
    return filled
