"""Field metadata shared by the settings dataclasses (a leaf module: every config may import it): which settings
keep their old behaviour at their default (``NEUTRAL_DEFAULT``) and the range each number may take (``bounded``,
``lengths``), which one walk of a whole configuration (``range_problem``) checks before anything is built."""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Iterator, Mapping

NEUTRAL_DEFAULT = {"neutral_default": True}
"""Metadata of a setting added after runs were recorded whose default is the behaviour from before it
existed: ``mapping.pipeline.records.settings_record`` leaves it out at its default, so rows recorded
before it stay valid."""
RANGE = "range"
"""The metadata key of a field's ``Range``."""


@dataclass(frozen=True)
class Range:
    """The values one setting may take: a number from ``low`` to ``high`` (each end included unless its
    ``*_open``), never NaN; or, with ``length``, a list of that many values each in ``items``."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    length: tuple[int, int] | None = None
    items: Range | None = None

    def contains(self, value: Any) -> bool:
        """Whether ``value`` is a number (not a bool, not NaN) inside the range."""
        if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value):
            return False
        above = self.low is None or (value > self.low if self.low_open else value >= self.low)
        below = self.high is None or (value < self.high if self.high_open else value <= self.high)
        return above and below

    def describe(self, integer: bool) -> str:
        """The range as a person reads it: ``an integer >= 1 and <= 8``, ``a finite number > 0 and <= 1``."""
        ends = [f"{'>' if self.low_open else '>='} {number_text(self.low)}" if self.low is not None else "",
                f"{'<' if self.high_open else '<='} {number_text(self.high)}" if self.high is not None else ""]
        return ("an integer " if integer else "a finite number ") + " and ".join(e for e in ends if e)

    def problem(self, value: Any, path: str, integer: bool = False, optional: bool = False) -> str | None:
        """Why ``value`` (the setting at ``path``) is outside the range, or None when it is inside."""
        if value is None and optional:
            return None
        if self.length is not None:
            return self._list_problem(value, path, integer, optional)
        if self.contains(value) and (not integer or isinstance(value, int)):
            return None
        return f"{path} must be {'None or ' if optional else ''}{self.describe(integer)}, got {value!r}"

    def _list_problem(self, value: Any, path: str, integer: bool, optional: bool) -> str | None:
        low, high = self.length
        if not isinstance(value, (list, tuple)) or not low <= len(value) <= high:
            count = len(value) if isinstance(value, (list, tuple)) else value
            return f"{path} must {'be None or ' if optional else ''}hold {low} to {high} values, got {count!r}"
        for i, item in enumerate(value):
            problem = self.items.problem(item, f"{path}[{i}]", integer) if self.items is not None else None
            if problem:
                return problem
        return None


def number_text(value: float) -> str:
    """A bound as written in a message: ``8``, ``0.5``, ``1e6``, ``1e-3``."""
    if isinstance(value, int):
        return str(value)
    mantissa, _, exponent = f"{value:g}".partition("e")
    return mantissa if not exponent else f"{mantissa}e{int(exponent)}"


def bounded(low: float | None, high: float | None, *, low_open: bool = False, high_open: bool = False,
            also: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Field metadata saying the setting is a number from ``low`` to ``high`` (``also``: other metadata kept,
    e.g. ``NEUTRAL_DEFAULT``)."""
    return {**(also or {}), RANGE: Range(low, high, low_open, high_open)}


def lengths(low: int, high: int, items: Range | dict | None = None,
            also: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Field metadata saying the setting is a list of ``low`` to ``high`` values, each in ``items`` (a ``Range``
    or ``bounded``'s metadata)."""
    each = items.get(RANGE) if isinstance(items, dict) else items
    return {**(also or {}), RANGE: Range(length=(low, high), items=each)}


def field_range(f: dataclasses.Field) -> Range | None:
    """The ``Range`` of a dataclass field, or None when it has none."""
    return f.metadata.get(RANGE)


def range_problem(config: Any, prefix: str = "") -> str | None:
    """The first setting of ``config`` (a dataclass, nested ones walked) outside its field's range, as a message
    naming its dotted path, its value and the range; None when every setting is in range."""
    return next(range_problems(config, prefix), None)


def range_problems(config: Any, prefix: str = "") -> Iterator[str]:
    """Every setting of ``config`` outside its field's range (see ``range_problem``)."""
    hints = type_hints(type(config))
    for f in dataclasses.fields(config):
        value, path = getattr(config, f.name), prefix + f.name
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            yield from range_problems(value, path + ".")
            continue
        limits = field_range(f)
        if limits is not None:
            integer, optional = kind_facts(hints[f.name])
            problem = limits.problem(value, path, integer, optional)
            if problem:
                yield problem


@lru_cache(maxsize=None)
def type_hints(cls: type) -> dict[str, Any]:
    """``cls``'s field types, resolved once (the modules use ``from __future__ import annotations``)."""
    return typing.get_type_hints(cls)


def kind_facts(kind: Any) -> tuple[bool, bool]:
    """(whether the numbers of a field of type ``kind`` are integers, whether it may be None)."""
    args = typing.get_args(kind)
    optional = type(None) in args
    inner = [a for a in args if a is not type(None)] if optional else [kind]
    base = inner[0] if len(inner) == 1 else kind
    while typing.get_origin(base) is tuple:
        base = typing.get_args(base)[0]
    return base is int, optional


def unbounded_numbers(cls: type, prefix: str = "") -> list[str]:
    """The dotted paths of the int and float fields (lists of them included) under the dataclass ``cls`` that
    carry no ``Range``: what ``range_problem`` cannot check."""
    out = []
    hints = type_hints(cls)
    for f in dataclasses.fields(cls):
        kind, path = hints[f.name], prefix + f.name
        nested = [a for a in (kind, *typing.get_args(kind)) if dataclasses.is_dataclass(a)]
        if nested:
            out += unbounded_numbers(nested[0], path + ".")
        elif field_range(f) is None and _holds_numbers(kind):
            out.append(path)
    return out


def _holds_numbers(kind: Any) -> bool:
    if kind in (int, float):
        return True
    return any(_holds_numbers(a) for a in typing.get_args(kind) if a is not Ellipsis)
