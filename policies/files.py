"""Policy files: the weights as safetensors beside a JSON of the architecture, the observation layout
they were trained on, the team size, a SHA-256 of the weights and how they were made.

A file that does not fit is refused with a ``PolicyError`` that names the file and the problem: a missing
half, a JSON over ``MAX_JSON_BYTES`` (checked before it is read) or nested deeper than ``MAX_JSON_DEPTH``
(checked before it is parsed), one that does not parse or is not a policy, another observation layout, an
observation version that does not exist or another team size, weights whose hash differs from the recorded
one (tampered or truncated), tensors that do not fit the architecture, or weights that are not finite.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import tempfile
from pathlib import Path

import torch

from openmulti_env.environment.layout import (AGENT_FEATURES, LINK_FEATURES, MAP_CHANNELS, OBSERVATION_VERSION,
                                              OBSERVATION_VERSIONS)
from policies.network import CommPolicyNetwork, NetworkConfig
from policies.scripted import PolicyError

FORMAT = "openmulti-comm-policy"
VERSION = 1
MAX_JSON_BYTES = 1 << 20
"""Largest policy JSON read, 1 MiB: the shipped ``policies/trained/learned.json`` has 10 kB (the architecture,
the observation layout and a training record that is mostly the command and its settings), and every policy
JSON under docs/ at most 10.1 kB, so this is a hundred times what a policy needs; a larger file is refused
before a byte of it is read."""
MAX_JSON_DEPTH = 32
"""Deepest nesting of objects and arrays in a policy JSON: the shipped one nests 7. Python's json parser
recurses once per level (RecursionError near 1000), so deeper text is refused before it is parsed."""
_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)
"""A JSON string (escapes included): brackets inside it do not nest."""
_BRACKET = re.compile(r"[\[\]{}]")


def observation_layout() -> dict:
    """The parts of the observation the policy network reads (``map`` and ``comm``), by name: a file is refused
    when they differ. The env's observation version is recorded beside it (version 2 added ``links`` and
    ``instances``, which this network does not read, so a version-1 file with this layout still fits)."""
    return {"map_channels": list(MAP_CHANNELS), "link_features": list(LINK_FEATURES),
            "agent_features": list(AGENT_FEATURES)}


def policy_paths(path: str | Path) -> tuple[Path, Path]:
    """(JSON, safetensors) of a policy given either file or their common stem."""
    path = Path(path)
    stem = path.with_suffix("") if path.suffix in (".json", ".safetensors") else path
    return stem.with_suffix(".json"), stem.with_suffix(".safetensors")


def _write_atomic(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600: a policy file is for others to read too
    os.replace(tmp, path)


def save_policy(path: str | Path, network: CommPolicyNetwork, num_agents: int, training: dict) -> Path:
    """Write ``<stem>.safetensors`` and ``<stem>.json`` (atomically, weights first); returns the JSON's path."""
    from safetensors.torch import save  # noqa: PLC0415

    json_path, weights_path = policy_paths(path)
    json_path.parent.mkdir(parents=True, exist_ok=True)
    blob = save({k: v.detach().cpu().contiguous() for k, v in network.state_dict().items()})
    _write_atomic(weights_path, blob)
    record = {"format": FORMAT, "version": VERSION, "weights": weights_path.name,
              "sha256": hashlib.sha256(blob).hexdigest(), "num_agents": num_agents,
              "observation": observation_layout(), "observation_version": OBSERVATION_VERSION,
              "architecture": network.config.as_dict(), "training": training}
    _write_atomic(json_path, (json.dumps(record, indent=2) + "\n").encode())
    return json_path


def nesting_depth(text: str, limit: int) -> int:
    """How deep JSON objects and arrays nest in ``text`` (brackets inside strings skipped), counted no further
    than ``limit + 1``: Python's json parser recurses once per level, so the depth is checked before it runs."""
    depth = deepest = 0
    for bracket in _BRACKET.finditer(_STRING.sub('""', text)):
        depth += 1 if bracket.group() in "[{" else -1
        if depth > deepest:
            deepest = depth
            if deepest > limit:
                break
    return deepest


def _too_big(json_path: Path, size: int) -> PolicyError:
    """The refusal of a policy JSON of ``size`` bytes, over ``MAX_JSON_BYTES``."""
    return PolicyError(f"{json_path} is {size:,} bytes, over the {MAX_JSON_BYTES:,} bytes a policy JSON may have "
                       f"(the shipped one has about 10 kB): not a policy file, not read")


def read_json_text(json_path: Path) -> str:
    """The text of a policy JSON: its size taken with stat before a byte is read, and at most
    ``MAX_JSON_BYTES`` + 1 bytes read (a file that grew since the stat is refused too)."""
    try:
        size = json_path.stat().st_size
        if size > MAX_JSON_BYTES:
            raise _too_big(json_path, size)
        with json_path.open("rb") as f:
            data = f.read(MAX_JSON_BYTES + 1)
    except OSError as exc:
        raise PolicyError(f"{json_path} cannot be read ({exc})") from None
    if len(data) > MAX_JSON_BYTES:
        raise _too_big(json_path, len(data))
    try:
        return data.decode()
    except UnicodeDecodeError as exc:
        raise PolicyError(f"{json_path} is not valid JSON ({exc}); truncated or not a policy file") from None


def read_record(json_path: Path) -> dict:
    """The JSON record of a policy file, size and nesting bounded (``MAX_JSON_BYTES``, ``MAX_JSON_DEPTH``)."""
    text = read_json_text(json_path)
    if nesting_depth(text, MAX_JSON_DEPTH) > MAX_JSON_DEPTH:
        raise PolicyError(f"{json_path} nests objects and arrays more than {MAX_JSON_DEPTH} deep (the shipped "
                          "one nests 7): not a policy file, not parsed")
    try:
        record = json.loads(text)
    except ValueError as exc:  # JSONDecodeError, and integers over Python's digit limit
        raise PolicyError(f"{json_path} is not valid JSON ({exc}); truncated or not a policy file") from None
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise PolicyError(f"{json_path} is not an OpenMulti communication policy (no \"format\": \"{FORMAT}\")")
    return record


def check_observation_version(record: dict, json_path: Path) -> None:
    """The env observation version the policy was trained on must be one there has been
    (``OBSERVATION_VERSIONS``); files written before the version was recorded have none: version 1."""
    version = record.get("observation_version", 1)
    if type(version) is not int or version not in OBSERVATION_VERSIONS:  # type(): True is an int too
        what = "unknown (a newer release's?)" if type(version) is int else "not a whole number"
        raise PolicyError(f"{json_path} records observation_version {version!r}, {what}; this release reads "
                          f"observation versions {', '.join(map(str, OBSERVATION_VERSIONS))}")


def check_record(record: dict, json_path: Path, num_agents: int | None) -> None:
    """The record's format version, observation layout and version, and team size fit this package and team."""
    if record.get("version") != VERSION:
        raise PolicyError(f"{json_path} has policy format version {record.get('version')}; this package reads {VERSION}")
    if record.get("observation") != observation_layout():
        raise PolicyError(f"{json_path} was trained on another observation layout {record.get('observation')}; this "
                          f"env's is {observation_layout()}")
    check_observation_version(record, json_path)
    if num_agents is not None and record.get("num_agents") != num_agents:
        raise PolicyError(f"{json_path} is a policy for {record.get('num_agents')} agents; the team has {num_agents}")


def fitting_weights(record: dict, blob: bytes, json_path: Path) -> tuple[NetworkConfig, dict[str, torch.Tensor]]:
    """The recorded architecture and the tensors of ``blob``, whose shapes are compared with it on torch's meta
    device: a crafted architecture allocates nothing before the check."""
    from safetensors import SafetensorError  # noqa: PLC0415
    from safetensors.torch import load  # noqa: PLC0415

    try:
        config = NetworkConfig.from_dict(record["architecture"])
        weights = load(blob)
        with torch.device("meta"):
            expected = {k: tuple(v.shape) for k, v in CommPolicyNetwork(config).state_dict().items()}
        got = {k: tuple(v.shape) for k, v in weights.items()}
        if got != expected:
            wrong = sorted(k for k in set(got) | set(expected) if got.get(k) != expected.get(k))[:3]
            raise ValueError(f"tensors {wrong}: the file has {[got.get(k) for k in wrong]}, the architecture "
                             f"{[expected.get(k) for k in wrong]}")
    except (KeyError, TypeError, ValueError, OverflowError, RuntimeError, SafetensorError) as exc:
        raise PolicyError(f"{json_path}: the weights do not fit the recorded architecture ({exc})") from None
    return config, weights


def check_finite(weights: dict[str, torch.Tensor], weights_path: Path) -> None:
    """Every weight finite: one NaN makes every logit NaN, and a NaN logit is neither > 0 nor drawn, so such a
    policy would load and never send; an inf pins logits at +-inf (or NaN) whatever the agent observes."""
    for name, tensor in weights.items():
        bad = int((~torch.isfinite(tensor)).sum())
        if bad:
            raise PolicyError(f"{weights_path}: tensor {name!r} holds {bad} non-finite value(s) (NaN or inf); "
                              "its logits no longer follow the observation (a NaN logit never sends): retrain or take "
                              "another snapshot")


def load_policy(path: str | Path, num_agents: int | None = None) -> tuple[CommPolicyNetwork, dict]:
    """The network and JSON record of a policy file (PolicyError naming what does not fit)."""
    json_path, weights_path = policy_paths(path)
    for part in (json_path, weights_path):
        if not part.is_file():
            raise PolicyError(f"policy file {part} is missing (a policy is a .json and a .safetensors side by side)")
    record = read_record(json_path)
    check_record(record, json_path, num_agents)
    blob = weights_path.read_bytes()
    if hashlib.sha256(blob).hexdigest() != record.get("sha256"):
        raise PolicyError(f"{weights_path} does not match the SHA-256 recorded in {json_path.name}: the weights were "
                          "changed or truncated")
    config, weights = fitting_weights(record, blob, json_path)
    check_finite(weights, weights_path)
    network = CommPolicyNetwork(config)
    network.load_state_dict(weights)
    network.eval()
    return network, record
