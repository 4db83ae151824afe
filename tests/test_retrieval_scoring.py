"""Retrieval scoring: the query's head decides, the label term, encoder mismatch refused, repeated queries."""

from __future__ import annotations

import pytest

from mapping.evaluate.query_text import query_head
from mapping.evaluate.retrieval import EncoderMismatchError, RetrievalIndex, score_instances
from mapping.perception import CodeBook, CodeBookEntry
from mapping.perception.text_encoder import shared_text_encoder


@pytest.fixture(scope="module")
def encoder():
    return shared_text_encoder(name="mpnet", backend="numpy")


def book_of(encoder, entries: dict[int, tuple[str, str | None]]) -> CodeBook:
    feats = encoder.encode([c for c, _ in entries.values()])
    book = CodeBook({i: CodeBookEntry(c, f, confidence=0.9, label=label)
                     for (i, (c, label)), f in zip(entries.items(), feats)})
    book.text_encoder = encoder.name
    return book


ROOM = {1: ("a beige painted wall", "wall"), 2: ("a framed picture of a mountain lake", "picture"),
        3: ("a wooden writing desk", "desk"), 4: ("a black office chair", "chair"),
        5: ("a queen-size bed with a honey brown wooden frame", "bed"), 6: ("a bedside table in oak", "nightstand")}


@pytest.mark.parametrize("text, head", [
    ("the picture on the wall", "the picture"), ("the lamp in the corner of the living room", "the lamp"),
    ("the keyboard in front of the monitor", "the keyboard"), ("The chair at the desk.", "the chair"),
    ("the trash can in the kitchen", "the trash can"), ("something to sit on", None),
    ("where can I put my glasses by the bed", None), ("a place to keep my books", None), ("the sofa", None),
])
def test_query_head(text, head):
    assert query_head(text) == head


def test_relation_query_returns_the_target_not_its_context(encoder):
    book = book_of(encoder, ROOM)
    assert score_instances("the picture on the wall", book, encoder)[0].instance_id == 2
    assert score_instances("the chair at the desk", book, encoder)[0].instance_id == 4


def test_label_term_scores_what_the_instance_is(encoder):
    book = book_of(encoder, ROOM)
    hits = score_instances("somewhere to sleep", book, encoder)
    assert hits[0].instance_id == 5 and hits[0].terms == ("caption", "label")
    w = 0.6
    assert hits[0].score == pytest.approx((1 - w) * hits[0].caption_score + w * hits[0].label_score)
    caption_only = score_instances("somewhere to sleep", book, encoder, label_share=0.0)[0]
    assert caption_only.terms == ("caption",) and caption_only.score == pytest.approx(caption_only.caption_score)


def test_code_book_of_one_encoder_is_refused_by_the_other(encoder, tmp_path):
    minilm = shared_text_encoder(name="minilm", backend="numpy")
    book = book_of(minilm, {1: ("a wooden chair", "chair")})
    book.save(tmp_path, "agent_0")
    loaded = CodeBook.load(tmp_path, "agent_0")
    assert loaded.text_encoder == "minilm"
    with pytest.raises(EncoderMismatchError, match="'minilm' text encoder, the query uses 'mpnet'"):
        score_instances("a chair", loaded, encoder)
    loaded.text_encoder = None  # an old code book without the name: its feature size still tells
    assert loaded.encoder_name() == "minilm"
    with pytest.raises(EncoderMismatchError):
        RetrievalIndex(loaded, encoder)


def test_index_answers_repeated_queries_the_same(encoder):
    index = RetrievalIndex(book_of(encoder, ROOM), encoder)
    first = [h.instance_id for h in index.rank("somewhere to work")]
    assert first[0] == 3 and [h.instance_id for h in index.rank("somewhere to work")] == first
    with pytest.raises(ValueError, match="query is empty"):
        index.rank("  ")
