"""Policy files: the weights as safetensors beside a JSON of the architecture, the observation layout
they were trained on, the team size, a SHA-256 of the weights and how they were made.

A file that does not fit is refused with an error that names the problem: a missing half, a JSON that
does not parse or is not a policy, another observation layout or team size, weights whose hash differs
from the recorded one (tampered or truncated), or tensors that do not fit the architecture.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import torch

from policies.network import CommPolicyNetwork, NetworkConfig
from policies.observation import AGENT_FEATURES, LINK_FEATURES, MAP_CHANNELS, OBSERVATION_VERSION
from policies.scripted import PolicyError

FORMAT = "openmulti-comm-policy"
VERSION = 1


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


def load_policy(path: str | Path, num_agents: int | None = None) -> tuple[CommPolicyNetwork, dict]:
    """The network and JSON record of a policy file (PolicyError naming what does not fit)."""
    from safetensors import SafetensorError  # noqa: PLC0415
    from safetensors.torch import load  # noqa: PLC0415

    json_path, weights_path = policy_paths(path)
    for part in (json_path, weights_path):
        if not part.is_file():
            raise PolicyError(f"policy file {part} is missing (a policy is a .json and a .safetensors side by side)")
    try:
        record = json.loads(json_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise PolicyError(f"{json_path} is not valid JSON ({exc}); truncated or not a policy file") from None
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise PolicyError(f"{json_path} is not an OpenMulti communication policy (no \"format\": \"{FORMAT}\")")
    if record.get("version") != VERSION:
        raise PolicyError(f"{json_path} has policy format version {record.get('version')}; this package reads {VERSION}")
    if record.get("observation") != observation_layout():
        raise PolicyError(f"{json_path} was trained on another observation layout {record.get('observation')}; this "
                          f"env's is {observation_layout()}")
    if num_agents is not None and record.get("num_agents") != num_agents:
        raise PolicyError(f"{json_path} is a policy for {record.get('num_agents')} agents; the team has {num_agents}")
    blob = weights_path.read_bytes()
    if hashlib.sha256(blob).hexdigest() != record.get("sha256"):
        raise PolicyError(f"{weights_path} does not match the SHA-256 recorded in {json_path.name}: the weights were "
                          "changed or truncated")
    try:
        config = NetworkConfig.from_dict(record["architecture"])
        weights = load(blob)
        with torch.device("meta"):  # shapes only: a crafted architecture allocates nothing before the check
            expected = {k: tuple(v.shape) for k, v in CommPolicyNetwork(config).state_dict().items()}
        got = {k: tuple(v.shape) for k, v in weights.items()}
        if got != expected:
            wrong = sorted(k for k in set(got) | set(expected) if got.get(k) != expected.get(k))[:3]
            raise ValueError(f"tensors {wrong}: the file has {[got.get(k) for k in wrong]}, the architecture "
                             f"{[expected.get(k) for k in wrong]}")
        network = CommPolicyNetwork(config)
        network.load_state_dict(weights)
    except (KeyError, TypeError, ValueError, RuntimeError, SafetensorError) as exc:
        raise PolicyError(f"{json_path}: the weights do not fit the recorded architecture ({exc})") from None
    network.eval()
    return network, record
