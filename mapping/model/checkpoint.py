"""Checkpoints written atomically and read back with errors that name the file and the problem."""

from __future__ import annotations

import os
import pickle
from pathlib import Path
from typing import Any

import torch

CHECKPOINT_FORMAT = "openmulti-checkpoint"
CHECKPOINT_VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint file is missing, corrupt, or of another kind or version."""


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> Path:
    """Write ``payload`` (tensors, numbers, strings, nested dicts and lists: what ``load_checkpoint``'s
    ``weights_only`` reading accepts) to ``path`` atomically: a crash mid-write leaves the previous
    checkpoint intact."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save({"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "payload": payload}, tmp)
    os.replace(tmp, path)
    return path


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read a checkpoint written by ``save_checkpoint``.

    Raises:
        CheckpointError: the file is missing, unreadable, not a checkpoint of this project, or of a
            newer version.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: checkpoint not found")
    try:
        # weights_only: a checkpoint from someone else must not be able to run code on load
        data = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as exc:
        # weights_only refuses whatever is not tensors, numbers, strings, lists or dicts: bytes that are no
        # pickle program at all are corrupt; any object (a global, a class, a reduce call) is refused as unsafe
        detail = next((line.strip() for line in str(exc).splitlines() if "Unsupported" in line), str(exc)[:200])
        if "Unsupported operand" in detail:
            raise CheckpointError(f"{path}: corrupt or unreadable checkpoint ({detail})") from None
        raise CheckpointError(f"{path}: refused: the checkpoint holds a pickled object or an instruction other than "
                              f"tensors, numbers, strings, lists and dicts ({detail}); reading it could run code"
                              ) from None
    except Exception as exc:  # noqa: BLE001  (zip and storage errors have many types)
        raise CheckpointError(f"{path}: corrupt or unreadable checkpoint ({type(exc).__name__}: {exc})") from None
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: not an OpenMulti checkpoint")
    if data.get("version", 0) > CHECKPOINT_VERSION:
        raise CheckpointError(f"{path}: checkpoint version {data['version']} is newer than this code ({CHECKPOINT_VERSION})")
    return data["payload"]
