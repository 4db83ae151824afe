"""Training checkpoints that cannot run code when a run resumes from them.

SB3's ``PPO.load`` and RLlib's ``restore_from_path`` unpickle: a crafted checkpoint in a run folder (one
copied from elsewhere, or dropped in a shared folder) runs whatever it holds. So:

- SB3: the checkpoint is ``checkpoint.pt``, tensors, numbers and strings only (the policy's and the
  optimiser's state and the step counters), read with ``torch.load(weights_only=True)``: an object of any
  other kind is refused, never built. An older ``checkpoint.zip`` is refused with how to start again.
- RLlib's checkpoint format is its own (pickled state): each checkpoint this package writes is signed
  (HMAC-SHA256 over its files, with a key kept in the user's cache folder, readable by the user only), and
  only a checkpoint whose signature matches is restored: one written elsewhere, edited or unsigned is
  refused with the reason.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import pickle
import secrets
from pathlib import Path

import torch

from policies.scripted import PolicyError

FORMAT = "openmulti.training-checkpoint"
VERSION = 1
SIGNATURE_NAME = "openmulti-signature.json"


class UnsafeCheckpointError(PolicyError):
    """A training checkpoint that could run code when read, or whose origin cannot be verified."""


def save_training_state(path: Path, state: dict, counters: dict[str, int]) -> None:
    """``state`` (nested dicts / lists of tensors, numbers, strings) and ``counters`` into ``path``, atomically."""
    tmp = path.with_name(path.name + ".tmp")
    torch.save({"format": FORMAT, "version": VERSION, "counters": dict(counters), "state": state}, tmp)
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


# ---- RLlib: signed checkpoint folders -----------------------------------------------------------------------
def sign_checkpoint(folder: Path, key_dir: Path | None = None) -> None:
    """Write the signature of every file in ``folder`` (call after RLlib wrote it, before it is swapped in)."""
    signature = {"format": FORMAT + ".signature", "version": VERSION, "hmac_sha256": _digest(folder, key_dir)}
    (folder / SIGNATURE_NAME).write_text(json.dumps(signature))


def verify_checkpoint(folder: Path, key_dir: Path | None = None) -> None:
    """UnsafeCheckpointError unless ``folder`` carries this user's signature over exactly its files."""
    try:
        signature = json.loads((folder / SIGNATURE_NAME).read_text())
        recorded = str(signature["hmac_sha256"])
    except (OSError, ValueError, KeyError, TypeError):
        raise UnsafeCheckpointError(
            f"{folder} carries no signature of this package (an older release's, or one written elsewhere): RLlib "
            "restores by unpickling, which could run code, so it is not read. Delete it (or train into a new "
            "--out) to start again") from None
    if not hmac.compare_digest(recorded, _digest(folder, key_dir)):
        raise UnsafeCheckpointError(
            f"{folder} was changed after it was written, or written with another user's key: RLlib restores by "
            "unpickling, which could run code, so it is not read. Delete it (or train into a new --out) to start "
            "again")


def _digest(folder: Path, key_dir: Path | None) -> str:
    mac = hmac.new(_key(key_dir), digestmod=hashlib.sha256)
    for path in sorted(p for p in folder.rglob("*") if p.is_file() and p.name != SIGNATURE_NAME):
        name = path.relative_to(folder).as_posix().encode()
        mac.update(len(name).to_bytes(8, "little") + name)
        with open(path, "rb") as f:
            data = f.read()
        mac.update(len(data).to_bytes(8, "little") + data)
    return mac.hexdigest()


def user_cache_folder() -> Path:
    """``$OPENMULTI_CACHE``, else ``$XDG_CACHE_HOME/openmulti``, else ``~/.cache/openmulti`` (the folder
    ``mapping.perception.model_cache.cache_root`` names; ``policies`` imports nothing of ``mapping``)."""
    if os.environ.get("OPENMULTI_CACHE"):
        return Path(os.environ["OPENMULTI_CACHE"]).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "openmulti"


def _key(key_dir: Path | None) -> bytes:
    """This user's signing key (made on first use, readable by the user only)."""
    path = (key_dir or user_cache_folder()) / "checkpoint-signing.key"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(secrets.token_bytes(32))
        try:
            os.link(tmp, path)  # the first writer's key wins when two processes race
        except FileExistsError:
            pass
        finally:
            tmp.unlink(missing_ok=True)
    return path.read_bytes()
