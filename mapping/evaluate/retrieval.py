"""Open-vocabulary instance retrieval: rank code-book instances by similarity to a text query.

Paper, sec. IV-E: the query is encoded by the caption encoder (SBERT) and by the image-text encoder
(CLIP); an instance scores the weighted sum of the cosines with its caption feature and its visual
feature (OpenObj: 0.2 caption, 0.8 visual). Two additions, because long captions dilute the match
("a queen-size bed with a honey brown wooden frame" vs "somewhere to sleep") and because a query may
name a thing by where it is ("the picture on the wall"):

- text term = (1 - label_share) * cos(SBERT(q), caption_i) + label_share * cos(SBERT(q), SBERT("a {label_i}")),
  the label being the instance's (zero-shot) category: what the instance is, not only how it was
  described; an instance without a label keeps the caption cosine alone;
- when ``query_head`` finds a relation ("the picture | on the wall"), the text term is
  (1 - context_weight) * text(head) + context_weight * text(whole query): the head decides. On the
  query set's tuning half the head alone (context_weight 0) scored best, so that is the default.

score = (visual_weight * visual + caption_weight * text) / (visual_weight + caption_weight) when an
image-text encoder is given and some instance has a visual feature (a missing one counts 0, so
scores stay comparable); else score = text. ``RetrievalIndex`` keeps the encoded code book so that
repeated queries cost one query encoding each.

No PettingZoo, Gymnasium, pyrender or ``openmulti_env`` imports here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mapping.evaluate.query_text import query_head
from mapping.perception.codebook import CodeBook

__all__ = ["EncoderMismatchError", "RetrievalHit", "RetrievalIndex", "RetrievalWeights", "LABEL_PROMPT",
           "check_encoder", "score_instances"]

LABEL_PROMPT = "a {}"
"""How an instance's label becomes text for the label term ("coffee_table" -> "a coffee table")."""


class EncoderMismatchError(ValueError):
    """The code book's caption features come from another text encoder than the query's."""


@dataclass(frozen=True)
class RetrievalWeights:
    """Weights of the score's terms (defaults tuned on the query set's tuning half only).

    Attributes:
        visual_weight: weight of the visual (CLIP) cosine when present (OpenObj: 0.8).
        caption_weight: weight of the text term beside it (OpenObj: 0.2).
        label_share: share of the label cosine inside the text term, in [0, 1].
        context_weight: share of the whole query beside its head for relation queries, in [0, 1].
    """

    visual_weight: float = 0.8
    caption_weight: float = 0.2
    label_share: float = 0.6
    context_weight: float = 0.0

    def __post_init__(self) -> None:
        if self.visual_weight < 0 or self.caption_weight < 0 or self.visual_weight + self.caption_weight <= 0:
            raise ValueError(f"weights must be >= 0 with a positive sum, got visual {self.visual_weight}, "
                             f"caption {self.caption_weight}")
        for name in ("label_share", "context_weight"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")


@dataclass(frozen=True)
class RetrievalHit:
    """One instance's answer to a query.

    Attributes:
        instance_id: code-book id.
        caption: the instance's caption text.
        label: its zero-shot (or code-book) category, None when unlabelled.
        score: combined similarity, higher is better (in [-1, 1]).
        caption_score: cosine between the query's (head's) and the caption's SBERT features.
        label_score: cosine between the query's (head's) feature and the label's, or None.
        visual_score: cosine between the query's image-text feature and the visual feature, or None.
        terms: the terms that made ``score``, e.g. ("caption", "label") or ("visual", "caption").
    """

    instance_id: int
    caption: str
    label: str | None
    score: float
    caption_score: float
    visual_score: float | None
    terms: tuple[str, ...]
    label_score: float | None = None


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    if not np.all(np.isfinite(v)) or np.any(norm == 0):
        raise ValueError(f"{what} has non-finite or zero-length feature vectors")
    return v / norm


def check_encoder(codebook: CodeBook, text_encoder) -> None:
    """Refuse a query encoder other than the one that made the code book's caption features.

    Raises:
        EncoderMismatchError: the names differ (or, with unnamed ones, the feature sizes).
    """
    book = codebook.encoder_name() if hasattr(codebook, "encoder_name") else None
    query = getattr(text_encoder, "name", None)
    if book is not None and query is not None and book != query:
        raise EncoderMismatchError(f"the code book's caption features were made by the {book!r} text encoder, "
                                   f"the query uses {query!r}: query with text_encoder={book!r} "
                                   f"(--text-encoder {book}) or remake the run")


class RetrievalIndex:
    """A code book encoded once for many queries (``rank(query)``).

    Args:
        codebook: instance id -> entry with a caption feature and maybe a visual feature.
        text_encoder: has ``encode(texts) -> (n, D)``; must be the code book's encoder.
        image_encoder: None, or has ``encode_texts(texts) -> (n, E)`` (a CLIP-like text tower).
        labels: instance id -> category; defaults to the code book's labels.
        weights: the score's weights (``RetrievalWeights``).
    """

    def __init__(self, codebook: CodeBook, text_encoder, image_encoder=None, labels: dict[int, str] | None = None,
                 weights: RetrievalWeights = RetrievalWeights()):
        check_encoder(codebook, text_encoder)
        self.codebook, self.text_encoder, self.image_encoder, self.weights = codebook, text_encoder, image_encoder, weights
        self.ids = sorted(codebook)
        labels = labels if labels is not None else {i: codebook[i].label for i in self.ids}
        self.labels = {i: labels.get(i) for i in self.ids}
        if not self.ids:
            return
        self.captions = _unit(np.stack([np.asarray(codebook[i].caption_feature).reshape(-1) for i in self.ids]),
                              "the code book's caption features")
        names = sorted({label for label in self.labels.values() if label})
        prompts = [LABEL_PROMPT.format(n.replace("_", " ")) for n in names]
        label_features = _unit(np.asarray(text_encoder.encode(prompts)), "the encoded labels") if names else None
        row = {n: k for k, n in enumerate(names)}
        self.has_label = np.array([self.labels[i] is not None for i in self.ids])
        self.label_rows = np.array([row.get(self.labels[i], 0) for i in self.ids])
        self.label_features = label_features
        self.visual: dict[int, np.ndarray] = {}
        if image_encoder is not None and weights.visual_weight > 0:
            self.visual = {i: _unit(np.asarray(codebook[i].visual_feature).reshape(-1), f"the visual feature of instance {i}")
                           for i in self.ids if codebook[i].visual_feature is not None}

    def _text_scores(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """(caption cosines, label cosines or None, text term) for one unit query feature."""
        if self.captions.shape[1] != q.shape[0]:
            raise EncoderMismatchError(f"caption features have {self.captions.shape[1]} dims, the text encoder "
                                       f"gives {q.shape[0]}: the code book was made by another encoder")
        caption = self.captions @ q
        if self.label_features is None:
            return caption, None, caption
        label = (self.label_features @ q)[self.label_rows]
        share = self.weights.label_share * self.has_label
        return caption, np.where(self.has_label, label, np.nan), (1 - share) * caption + share * np.where(self.has_label, label, 0)

    def rank(self, query: str) -> list[RetrievalHit]:
        """Every instance's similarity to ``query``, best first (ties broken by the smaller id)."""
        if not isinstance(query, str) or not query.strip():
            raise ValueError("the retrieval query is empty: give some text, e.g. 'somewhere to sleep'")
        if not self.ids:
            return []
        query = query.strip()
        head = query_head(query)
        texts = [query] if head is None else [head, query]
        feats = _unit(np.asarray(self.text_encoder.encode(texts)), "the encoded query")
        caption, label, text = self._text_scores(feats[0])
        if head is not None:
            _, _, whole = self._text_scores(feats[1])
            text = (1 - self.weights.context_weight) * text + self.weights.context_weight * whole

        visual_scores: dict[int, float] = {}
        if self.visual:
            q_img = _unit(np.asarray(self.image_encoder.encode_texts([query]))[0], "the image encoder's query feature")
            for i, v in self.visual.items():
                if v.shape != q_img.shape:
                    raise ValueError(f"instance {i}: visual feature has {v.shape[0]} dims, the image encoder "
                                     f"gives {q_img.shape[0]}")
                visual_scores[i] = float(v @ q_img)

        w = self.weights
        hits = []
        for k, i in enumerate(self.ids):
            text_terms = ("caption", "label") if label is not None and self.has_label[k] and w.label_share > 0 else ("caption",)
            if visual_scores:
                score = (w.visual_weight * visual_scores.get(i, 0.0) + w.caption_weight * text[k]) / (w.visual_weight + w.caption_weight)
                terms = (("visual",) if i in visual_scores else ()) + text_terms
            else:
                score, terms = text[k], text_terms
            label_score = None if label is None or not self.has_label[k] else float(label[k])
            hits.append(RetrievalHit(int(i), self.codebook[i].caption, self.labels[i], float(score), float(caption[k]),
                                     visual_scores.get(i), terms, label_score))
        hits.sort(key=lambda h: (-h.score, h.instance_id))
        return hits


def score_instances(
    query: str,
    codebook: CodeBook,
    text_encoder,
    image_encoder=None,
    visual_weight: float = 0.8,
    caption_weight: float = 0.2,
    labels: dict[int, str] | None = None,
    label_share: float = RetrievalWeights.label_share,
    context_weight: float = RetrievalWeights.context_weight,
) -> list[RetrievalHit]:
    """Every instance's similarity to ``query``, best first (see the module docstring for the score).

    One-shot form of ``RetrievalIndex(...).rank(query)``; keep an index for many queries.

    Raises:
        ValueError: blank query or bad weights; EncoderMismatchError: the code book's encoder differs.
    """
    if not isinstance(query, str) or not query.strip():
        raise ValueError("the retrieval query is empty: give some text, e.g. 'somewhere to sleep'")
    weights = RetrievalWeights(visual_weight, caption_weight, label_share, context_weight)
    return RetrievalIndex(codebook, text_encoder, image_encoder, labels, weights).rank(query)
