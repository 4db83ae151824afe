"""The code book: instance id -> (visual feature or none, caption feature, caption text, confidence).

Semantic features live here, not in the networks (paper, sec. III-D). Saved as ``NAME.json`` (ids,
captions, confidences, labels, the text encoder that made the caption features) beside ``NAME.npz``
(the feature arrays), each written atomically. Caption features of two encoders live in different
spaces, so a code book knows its encoder (``text_encoder``) and retrieval refuses another one.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mapping.safe_parse import load_json


class CodeBookError(ValueError):
    """A code book file is missing, corrupt or inconsistent."""


@dataclass
class CodeBookEntry:
    """What the map knows about one instance's meaning.

    Attributes:
        caption: caption text.
        caption_feature: (D,) float32 unit vector of the code book's text encoder (768 mpnet, 384 minilm).
        visual_feature: (D,) float32 unit vector, or None when no image-text encoder is loaded.
        confidence: eq. 1-2, in [0, 1].
        label: zero-shot category, filled by the semantic evaluation (None before).
    """

    caption: str
    caption_feature: np.ndarray
    visual_feature: np.ndarray | None = None
    confidence: float = 0.0
    label: str | None = None


ENCODER_BY_DIM = {768: "mpnet", 384: "minilm"}
"""The text encoder a caption-feature size implies, for code books that do not name theirs."""


class CodeBook(dict):
    """``dict[int, CodeBookEntry]`` with atomic save / load.

    Attributes:
        text_encoder: name of the text encoder that made the caption features ("mpnet", "minilm"),
            or None: then ``encoder_name()`` infers it from the feature size.
    """

    text_encoder: str | None = None

    def encoder_name(self) -> str | None:
        """``text_encoder`` when set, else the encoder implied by the caption-feature size (None if empty)."""
        if self.text_encoder is not None or not self:
            return self.text_encoder
        dim = int(np.asarray(next(iter(self.values())).caption_feature).size)
        return ENCODER_BY_DIM.get(dim)

    def save(self, directory: str | Path, name: str) -> Path:
        """Write ``directory/name.json`` and ``directory/name.npz``; returns the JSON path."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        ids = sorted(self)
        arrays = {f"caption_{i}": np.asarray(self[i].caption_feature, np.float32) for i in ids}
        arrays.update({f"visual_{i}": np.asarray(self[i].visual_feature, np.float32)
                       for i in ids if self[i].visual_feature is not None})
        meta = {"version": 2, "text_encoder": self.encoder_name(), "instances": [{"id": int(i), "caption": self[i].caption,
                                              "confidence": float(self[i].confidence), "label": self[i].label,
                                              "has_visual": self[i].visual_feature is not None} for i in ids]}
        npz = directory / f"{name}.npz"
        _atomic_write(npz, lambda f: np.savez(f, **arrays))
        meta["npz_sha256"] = hashlib.sha256(npz.read_bytes()).hexdigest()  # pairs the two files
        path = directory / f"{name}.json"
        _atomic_write(path, lambda f: f.write(json.dumps(meta, indent=1).encode()))
        return path

    @classmethod
    def load(cls, directory: str | Path, name: str) -> "CodeBook":
        """Read a code book written by ``save`` (CodeBookError naming the file when unusable)."""
        json_path, npz_path = Path(directory) / f"{name}.json", Path(directory) / f"{name}.npz"
        for p in (json_path, npz_path):
            if not p.is_file():
                raise CodeBookError(f"code book file missing: {p}")
        try:
            meta = load_json(json_path)
            if meta.get("npz_sha256") not in (None, hashlib.sha256(npz_path.read_bytes()).hexdigest()):
                raise CodeBookError(f"{npz_path} does not belong to {json_path} (written by another save)")
            with np.load(npz_path) as arrays:
                book = cls()
                for rec in meta["instances"]:
                    i = int(rec["id"])
                    book[i] = CodeBookEntry(rec["caption"], arrays[f"caption_{i}"],
                                            arrays[f"visual_{i}"] if rec["has_visual"] else None,
                                            float(rec["confidence"]), rec.get("label"))
                book.text_encoder = meta.get("text_encoder") or book.encoder_name()  # version 1: by size
        except (ValueError, KeyError, TypeError, OSError) as exc:
            raise CodeBookError(f"corrupt code book {json_path} / {npz_path}: {exc}") from exc
        return book


def _atomic_write(path: Path, write) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
