"""Open-vocabulary instance retrieval: rank code-book instances by similarity to a text query.

Paper, sec. IV-E: the query text is encoded by the caption encoder (SBERT) and by the image-text
encoder (CLIP); each instance scores the weighted sum of the cosine similarities with its caption
feature and its visual feature, and the best instance answers. OpenObj weights them 0.2 (caption)
and 0.8 (visual). Without an image-text encoder (or for an instance without a visual feature) only
the caption term is left and the score is its cosine similarity.

No PettingZoo, Gymnasium, pyrender or ``openmulti_env`` imports here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mapping.perception.codebook import CodeBook

__all__ = ["RetrievalHit", "score_instances"]


@dataclass(frozen=True)
class RetrievalHit:
    """One instance's answer to a query.

    Attributes:
        instance_id: code-book id.
        caption: the instance's caption text.
        label: its zero-shot (or code-book) category, None when unlabelled.
        score: combined similarity, higher is better (a cosine, in [-1, 1]).
        caption_score: cosine between the query's and the caption's SBERT features.
        visual_score: cosine between the query's image-text feature and the visual feature, or None.
        terms: the terms that made ``score``: ("caption",) or ("visual", "caption").
    """

    instance_id: int
    caption: str
    label: str | None
    score: float
    caption_score: float
    visual_score: float | None
    terms: tuple[str, ...]


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    if not np.all(np.isfinite(v)) or np.any(norm == 0):
        raise ValueError(f"{what} has non-finite or zero-length feature vectors")
    return v / norm


def score_instances(
    query: str,
    codebook: CodeBook,
    text_encoder,
    image_encoder=None,
    visual_weight: float = 0.8,
    caption_weight: float = 0.2,
    labels: dict[int, str] | None = None,
) -> list[RetrievalHit]:
    """Every instance's similarity to ``query``, best first (ties broken by the smaller id).

    score = (visual_weight * cos(v_i, E_img(q)) + caption_weight * cos(c_i, SBERT(q)))
    / (visual_weight + caption_weight) when ``image_encoder`` is given and some instance has a visual
    feature; an instance without one then scores its visual term as 0 (the same formula for all, so
    scores stay comparable: CLIP and SBERT cosines have different ranges). Without visual features
    anywhere: cos(c_i, SBERT(q)).

    Args:
        query: free text ("somewhere to sleep"); must not be blank.
        codebook: instance id -> entry with a (384,) caption feature and maybe a (D,) visual feature.
        text_encoder: has ``encode(texts) -> (n, 384)`` (``TextEncoder``).
        image_encoder: None, or has ``encode_texts(texts) -> (n, D)`` (a CLIP-like text tower).
        visual_weight, caption_weight: weights of the two terms (OpenObj: 0.8 and 0.2), >= 0.
        labels: instance id -> category for the hits; defaults to the code book's labels.
    """
    if not isinstance(query, str) or not query.strip():
        raise ValueError("the retrieval query is empty: give some text, e.g. 'somewhere to sleep'")
    if visual_weight < 0 or caption_weight < 0 or visual_weight + caption_weight <= 0:
        raise ValueError(f"weights must be >= 0 with a positive sum, got visual {visual_weight}, "
                         f"caption {caption_weight}")
    if not codebook:
        return []
    query = query.strip()
    ids = sorted(codebook)
    captions = _unit(np.stack([np.asarray(codebook[i].caption_feature).reshape(-1) for i in ids]),
                     "the code book's caption features")
    q_text = _unit(np.asarray(text_encoder.encode([query]))[0], "the encoded query")
    if captions.shape[1] != q_text.shape[0]:
        raise ValueError(f"caption features have {captions.shape[1]} dims, the text encoder gives {q_text.shape[0]}")
    caption_scores = captions @ q_text

    visual_scores: dict[int, float] = {}
    use_visual = image_encoder is not None and visual_weight > 0
    if use_visual and any(codebook[i].visual_feature is not None for i in ids):
        q_img = _unit(np.asarray(image_encoder.encode_texts([query]))[0], "the image encoder's query feature")
        for i in ids:
            v = codebook[i].visual_feature
            if v is not None:
                v = _unit(np.asarray(v).reshape(-1), f"the visual feature of instance {i}")
                if v.shape != q_img.shape:
                    raise ValueError(f"instance {i}: visual feature has {v.shape[0]} dims, the image encoder "
                                     f"gives {q_img.shape[0]}")
                visual_scores[i] = float(v @ q_img)

    labels = labels if labels is not None else {i: codebook[i].label for i in ids}
    hits = []
    for i, cap in zip(ids, caption_scores):
        if visual_scores:  # one formula for every instance; a missing visual feature counts 0
            score = (visual_weight * visual_scores.get(i, 0.0) + caption_weight * cap) / (visual_weight + caption_weight)
            terms: tuple[str, ...] = ("visual", "caption") if i in visual_scores else ("caption",)
        else:
            score, terms = float(cap), ("caption",)
        hits.append(RetrievalHit(int(i), codebook[i].caption, labels.get(i), float(score), float(cap),
                                 visual_scores.get(i), terms))
    hits.sort(key=lambda h: (-h.score, h.instance_id))
    return hits
