"""Training checkpoints that cannot run code when a run resumes from them.

SB3's ``PPO.load`` and RLlib's ``restore_from_path`` unpickle: a crafted checkpoint in a run folder (one
copied from elsewhere, or dropped in a shared folder) runs whatever it holds. So neither is used. Both backends
write ``checkpoint.pt``: tensors, numbers and strings only (the policy's and the optimiser's state and the step
counters), read with ``torch.load(weights_only=True)``: an object of any other kind is refused, never built. On
resume the algorithm is rebuilt from the run's settings and only this state is put into it. An older release's
pickled checkpoints (SB3's ``checkpoint.zip``, RLlib's ``checkpoint/`` folder) are refused with how to start
again, never read.
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import torch

from policies.scripted import PolicyError

FORMAT = "openmulti.training-checkpoint"
VERSION = 1


class UnsafeCheckpointError(PolicyError):
    """A training checkpoint that could run code when read, or whose origin cannot be verified."""


def save_training_state(path: Path, state: dict, counters: dict[str, int]) -> None:
    """``state`` (nested dicts / lists of tensors, numbers, strings) and ``counters`` into ``path``, atomically.

    The temporary file is created new (``O_EXCL``): a symlink planted under its name is replaced, never followed."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.unlink(missing_ok=True)
    with os.fdopen(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), "wb") as f:
        torch.save({"format": FORMAT, "version": VERSION, "counters": dict(counters), "state": state}, f)
    os.replace(tmp, path)


def load_training_state(path: Path) -> tuple[dict, dict[str, int]]:
    """The state and counters of ``save_training_state``; UnsafeCheckpointError for anything else."""
    try:
        record = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        raise UnsafeCheckpointError(
            f"{path} holds objects other than tensors and numbers ({str(exc).splitlines()[0][:160]}); reading it "
            "could run code, so it is refused: delete it (or train into a new --out) to start again") from None
    except (RuntimeError, EOFError, OSError, ValueError) as exc:
        raise UnsafeCheckpointError(f"{path} is corrupt or truncated ({type(exc).__name__}: {str(exc)[:160]}); "
                                    "delete it (or train into a new --out) to start again") from None
    if not isinstance(record, dict) or record.get("format") != FORMAT or record.get("version") != VERSION:
        raise UnsafeCheckpointError(f"{path} is not an OpenMulti training checkpoint of version {VERSION}; delete "
                                    "it (or train into a new --out) to start again")
    counters = record.get("counters")
    if not isinstance(counters, dict) or not all(isinstance(v, int) and v >= 0 for v in counters.values()):
        raise UnsafeCheckpointError(f"{path}: its step counters are not non-negative integers")
    return record["state"], counters


def refuse_pickled_checkpoint(path: Path) -> None:
    """UnsafeCheckpointError when ``path`` (an older release's pickled SB3 ``checkpoint.zip``) exists."""
    if path.exists():
        raise UnsafeCheckpointError(
            f"{path} is a pickled SB3 checkpoint (written by an older release, or placed there): reading it could "
            f"run code, so it is not read. Delete it (or train into a new --out) to start again; checkpoints are "
            f"now {path.with_suffix('.pt').name}, tensors only")


def refuse_pickled_rllib_checkpoint(folder: Path) -> None:
    """UnsafeCheckpointError when ``folder`` (an older release's RLlib ``checkpoint/``: pickled state) exists."""
    if folder.exists():
        raise UnsafeCheckpointError(
            f"{folder} is an RLlib checkpoint folder (written by an older release, or placed there): RLlib restores "
            f"by unpickling, which could run code, so it is not read. Delete it (or train into a new --out) to start "
            f"again; checkpoints are now {folder.name}.pt, tensors only")


def tensors_only(state: Any, where: str = "state") -> Any:
    """``state`` with NumPy arrays as tensors and NumPy scalars as Python numbers (what ``weights_only`` reads):
    RLlib hands its module and optimiser state over as NumPy. ValueError naming the entry for anything else."""
    if isinstance(state, dict):
        return {key: tensors_only(value, f"{where}[{key!r}]") for key, value in state.items()}
    if isinstance(state, (list, tuple)):
        return type(state)(tensors_only(value, f"{where}[{i}]") for i, value in enumerate(state))
    if isinstance(state, np.ndarray):
        return torch.tensor(state)  # a copy, 0-d arrays (Adam's step) kept 0-d
    if isinstance(state, np.generic):
        return state.item()
    if state is None or isinstance(state, (torch.Tensor, bool, int, float, str)):
        return state
    raise ValueError(f"{where} is a {type(state).__name__}: a training checkpoint holds tensors, numbers and "
                     "strings only")
