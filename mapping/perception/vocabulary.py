"""The categories a team labels its instances with: names, their encoded zero-shot prompts, and which are
walls, floor and ceiling. A source (simulated world or data set) builds it; the team labels each instance
by it (and gives structure its wider networks); evaluation encodes the same prompts to score."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

CATEGORY_PROMPT = "a {} in a room"
"""How a category name becomes text before SBERT encodes it. Measured on the 214 metadata captions of
the eight scene presets against the 34 simulator categories (python -m studies.retrieval): bare name
79.0 % correct, "a {}" 82.2 %, "a photo of a {}" 88.3 %, "a {} in a room" 89.7 %. The rest are
near-synonym classes (plant / potted_plant, picture / window_frame, pillow / sofa)."""


def category_prompts(category_names: Sequence[str], prompt: str = CATEGORY_PROMPT) -> list[str]:
    """Texts to encode for category names: underscores become spaces ("coffee_table" -> "coffee table")."""
    return [prompt.format(str(name).replace("_", " ")) for name in category_names]


@dataclass
class Vocabulary:
    """Category names with their encoded prompts; which of them are walls, floor, ceiling."""

    names: list[str]
    features: np.ndarray  # (C, d) unit rows
    structure: frozenset[str] = frozenset({"wall", "floor", "ceiling"})

    @staticmethod
    def from_encoder(names: Sequence[str], text_encoder, structure: Sequence[str] = ("wall", "floor", "ceiling")
                     ) -> "Vocabulary":
        """Encode "a {name} in a room" for each name (``CATEGORY_PROMPT``, as zero-shot evaluation does)."""
        names = list(dict.fromkeys(names))
        features = np.asarray(text_encoder.encode(category_prompts(names)), np.float32)
        features /= np.maximum(np.linalg.norm(features, axis=1, keepdims=True), 1e-12)
        return Vocabulary(names, features, frozenset(structure))

    def label(self, feature: np.ndarray) -> str:
        """The zero-shot category of a caption feature (cosine to the prompts)."""
        return self.names[int(np.argmax(self.features @ np.asarray(feature, np.float32)))]
