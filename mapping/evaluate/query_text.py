"""The head of a retrieval query: "the picture on the wall" asks for the picture, not the wall.

A query that names a thing by where it is puts the target first and the context after a relation
word. The rule: split at the first relation word (or phrase) when the part before is a plain noun
phrase (it starts with a determiner and holds no word of a task or question, such as "to", "where",
"I") and the part after starts one too ("the", "a", "my", ...). Queries about a task ("where can I
put my glasses by the bed", "something to sit on") are left whole: their context is the point.

A parser (spaCy) would find heads in more shapes, but its English models are not shipped as
maintained PyPI packages and importing it costs about a second of the query budget; the query set's
relation queries follow this shape, and tests/test_retrieval_scoring.py pins the rule.
"""

from __future__ import annotations

import re

__all__ = ["RELATION_PHRASES", "query_head"]

RELATION_PHRASES: tuple[str, ...] = (
    "in front of", "on top of", "to the left of", "to the right of", "across from", "next to", "close to",
    "underneath", "beneath", "beside", "behind", "against", "between", "inside", "above", "below", "under",
    "near", "over", "with", "on", "in", "at", "by", "to",
)
"""Words that start a context phrase; longer phrases are tried first."""

_DETERMINERS = frozenset("the a an my our your his her their this that these those some".split())
_TASK_WORDS = frozenset("to i we you where what which how something somewhere "
                        "anything place thing stuff".split())
_RELATION = re.compile(r"\b(" + "|".join(re.escape(p) for p in RELATION_PHRASES) + r")\b")


def query_head(text: str) -> str | None:
    """The target noun phrase of a relation query, or None when the query names no relation.

    >>> query_head("the picture on the wall")
    'the picture'
    >>> query_head("the lamp in the corner of the living room")
    'the lamp'
    >>> query_head("something to sit on") is None
    True
    """
    words = re.sub(r"[^\w\s'-]", " ", text.lower()).split()
    clean = " ".join(words)
    for match in _RELATION.finditer(clean):
        head, rest = clean[:match.start()].split(), clean[match.end():].split()
        if _TASK_WORDS & set(head):
            return None  # a task or question: its context is the point
        if len(head) >= 2 and head[0] in _DETERMINERS and rest and rest[0] in _DETERMINERS:
            return " ".join(head)
    return None
