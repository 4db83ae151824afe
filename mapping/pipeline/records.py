"""Results and settings records on disk: written atomically (a crash never leaves half a file), plain JSON."""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path
from typing import Callable

from mapping.safe_parse import load_json


def write_json_atomic(path: Path, data: dict) -> None:
    """Write JSON (no NaN or inf allowed) through a temporary file and a rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, allow_nan=False))
    os.replace(tmp, path)


def finite_or_none(x: float) -> float | None:
    """A metric as a JSON number, or None when it is NaN or infinite (e.g. no reconstruction)."""
    return float(x) if math.isfinite(x) else None


def mean_or_none(values: list) -> float | None:
    """Mean of the values that are not None (None when there are none): the mean over agents."""
    vals = [float(v) for v in values if v is not None]
    return sum(vals) / len(vals) if vals else None


def forget_stale_checkpoints(out: Path, settings: dict, read_old: Callable[[dict], dict | None] | None = None) -> None:
    """Keep ``out/checkpoints/*.pt`` only if they were made with these ``settings`` (ids, masks and maps
    depend on all of them); otherwise delete them, so a resumed run never mixes two runs. ``read_old`` reads a
    record an older version wrote as this version's (None: it cannot be trusted)."""
    path = out / "checkpoints" / "run_settings.json"
    try:
        old = load_json(path)
        same = old == settings or (read_old is not None and isinstance(old, dict) and read_old(old) == settings)
    except (OSError, ValueError):  # no record (or an unreadable one): the checkpoints cannot be trusted
        same = False
    stale = [] if same else sorted((out / "checkpoints").glob("*.pt"))
    for ckpt in stale:
        ckpt.unlink()
    if stale:
        print(f"[openmulti] {out}: settings differ from the run that wrote its checkpoints; "
              f"deleted {len(stale)} checkpoint(s) and mapping again")
    write_json_atomic(path, settings)


def as_record(value) -> dict:
    """``value`` as it reads back from a JSON file (tuples as lists, inf as inf): what a settings record
    on disk is compared with."""
    return json.loads(json.dumps(plain(value)))


def settings_record(config) -> dict:
    """A dataclass config as a settings record (``as_record(asdict(config))``) without the fields whose
    metadata says ``neutral_default`` (``mapping.config_fields.NEUTRAL_DEFAULT``) that hold their default
    (nested dataclasses too): a setting added after rows were recorded, at the behaviour from before it
    existed, leaves those rows valid."""
    def strip(obj):
        if not dataclasses.is_dataclass(obj):
            return obj
        return {f.name: strip(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                if not (f.metadata.get("neutral_default") and getattr(obj, f.name) == default_of(f))}
    return as_record(strip(config))


def default_of(f: dataclasses.Field):
    """A field's default, made by its factory when it has one (a whole node such as ``team.exchange.codec``)."""
    return f.default_factory() if f.default is dataclasses.MISSING and f.default_factory is not dataclasses.MISSING \
        else f.default


def neutral_default_paths(config, prefix: tuple[str, ...] = ()) -> set[tuple[str, ...]]:
    """The key paths of a dataclass config's ``neutral_default`` fields that hold their default (nested
    dataclasses too): the settings a record written before they existed may lack and still mean the same."""
    paths: set[tuple[str, ...]] = set()
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if f.metadata.get("neutral_default") and value == default_of(f):
            paths.add(prefix + (f.name,))
        elif dataclasses.is_dataclass(value):
            paths |= neutral_default_paths(value, prefix + (f.name,))
    return paths


def missing_paths(old: dict, new: dict, prefix: tuple[str, ...] = ()) -> set[tuple[str, ...]] | None:
    """The key paths ``new`` has and ``old`` lacks, when the two agree everywhere else (None when a value
    differs or ``old`` has a key ``new`` lacks)."""
    if set(old) - set(new):
        return None
    paths: set[tuple[str, ...]] = set()
    for key, value in new.items():
        if key not in old:
            paths.add(prefix + (key,))
        elif isinstance(value, dict) and isinstance(old[key], dict):
            inner = missing_paths(old[key], value, prefix + (key,))
            if inner is None:
                return None
            paths |= inner
        elif old[key] != value:
            return None
    return paths


def plain(value):
    """Config dicts for JSON (tuples and frozensets as lists)."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [plain(v) for v in value]
    return value
