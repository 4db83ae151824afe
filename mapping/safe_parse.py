"""JSON and YAML read from files a user or another machine wrote (run configs, metrics, scene manifests, a data
set's ``cam_params.json``), parsed so that a hostile or careless file gives one ``ParseError`` naming it:

- at most ``MAX_BYTES`` of text and ``MAX_DEPTH`` levels of nesting (a deeply nested file would otherwise raise
  RecursionError from the parser, or from whatever walks the result later);
- a key given twice in one mapping is refused naming the key (JSON and YAML both keep the last silently);
- YAML is read safely (no tag builds an object) with YAML 1.2's numbers: ``1e12`` and ``1E-3`` are numbers, not
  the strings PyYAML's YAML 1.1 resolver makes of them; anchors may not expand past ``MAX_NODES`` values.

A leaf module: every part of ``mapping`` and ``openmulti_env`` may import it."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml

MAX_DEPTH = 64
"""Deepest nesting of lists and mappings a file may hold (a whole run config nests 5 levels; metrics 7)."""
MAX_BYTES = 256 * 2**20
"""Largest file read (a run's metrics.json is kilobytes; a scene manifest too)."""
MAX_NODES = 1_000_000
"""Most values a YAML document may expand to through its anchors and aliases."""
FLOAT_TAG = "tag:yaml.org,2002:float"
FLOAT_PATTERN = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
    |[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+\.[0-9_]*
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""", re.X)
"""YAML 1.1's float pattern with the exponent form without a dot (``1e12``) added."""
JSON_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"')
"""A JSON string literal (unrolled, so that it cannot backtrack badly)."""


class ParseError(ValueError):
    """A JSON or YAML file (or text) that cannot be read safely; the message names it and why."""


def load_json(path: str | Path, max_depth: int = MAX_DEPTH, max_bytes: int = MAX_BYTES) -> Any:
    """The JSON value in ``path`` (``ParseError`` naming the file when it is too large, too deep, holds a
    duplicated key or is not JSON; OSError when it cannot be read)."""
    return parse_json(read_text(path, max_bytes), str(path), max_depth)


def load_yaml(path: str | Path, max_depth: int = MAX_DEPTH, max_bytes: int = MAX_BYTES) -> Any:
    """The YAML value in ``path`` (as ``load_json``; YAML tags are refused)."""
    return parse_yaml(read_text(path, max_bytes), str(path), max_depth)


def load_data(path: str | Path, max_depth: int = MAX_DEPTH, max_bytes: int = MAX_BYTES) -> Any:
    """``path`` read as JSON when its suffix is ``.json``, else as YAML."""
    reader = load_json if Path(path).suffix.lower() == ".json" else load_yaml
    return reader(path, max_depth, max_bytes)


def read_text(path: str | Path, max_bytes: int = MAX_BYTES) -> str:
    """The text of ``path``, refused before reading when it is larger than ``max_bytes``."""
    path = Path(path)
    size = path.stat().st_size
    if size > max_bytes:
        raise ParseError(f"{path}: {size} bytes, more than the {max_bytes} a settings file may hold")
    try:
        return path.read_text()
    except UnicodeDecodeError as exc:
        raise ParseError(f"{path}: not UTF-8 text ({exc})") from None


def parse_json(text: str, source: str = "<text>", max_depth: int = MAX_DEPTH) -> Any:
    """The JSON value of ``text`` (``source`` names it in errors), its depth checked before parsing."""
    depth = json_depth(text)
    if depth > max_depth:
        raise ParseError(too_deep(source, max_depth))
    try:
        return json.loads(text, object_pairs_hook=lambda pairs: unique_keys(pairs, source))
    except json.JSONDecodeError as exc:
        raise ParseError(f"{source}: not valid JSON: {exc}") from None


def json_depth(text: str) -> int:
    """The deepest nesting of brackets in JSON ``text``, outside its strings (a linear scan, no recursion)."""
    brackets = np.frombuffer(re.sub(r"[^\[\]{}]+", "", JSON_STRING.sub("", text)).encode(), np.uint8)
    steps = np.where((brackets == ord("[")) | (brackets == ord("{")), 1, -1)
    return int(np.cumsum(steps).max()) if len(steps) else 0


def unique_keys(pairs: list[tuple[Any, Any]], source: str) -> dict:
    """A mapping of ``pairs``; ``ParseError`` naming the first key given twice."""
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise ParseError(f"{source}: key {key!r} appears twice in one mapping")
        out[key] = value
    return out


def parse_yaml(text: str, source: str = "<text>", max_depth: int = MAX_DEPTH) -> Any:
    """The YAML value of ``text`` (``source`` names it in errors): safe tags only, nesting and alias expansion
    bounded, duplicated keys refused, ``1e12`` a number."""
    loader = BoundedLoader(text, source, max_depth)
    try:
        data = loader.get_single_data()
    except yaml.YAMLError as exc:
        raise ParseError(f"{source}: not valid YAML: {exc}") from None
    finally:
        loader.dispose()
    check_expansion(data, source, max_depth)
    return data


def check_expansion(data: Any, source: str, max_depth: int = MAX_DEPTH, max_nodes: int = MAX_NODES) -> None:
    """``ParseError`` when ``data`` nests deeper than ``max_depth`` or holds more than ``max_nodes`` values once its
    shared parts (YAML aliases) are counted each time they appear; a walk with its own stack, no recursion."""
    stack, count = [(data, 1)], 0
    while stack:
        value, depth = stack.pop()
        count += 1
        if count > max_nodes:
            raise ParseError(f"{source}: expands to more than {max_nodes} values (anchors and aliases)")
        if isinstance(value, (list, dict)):
            if depth > max_depth:
                raise ParseError(too_deep(source, max_depth))
            children = value.values() if isinstance(value, dict) else value
            stack.extend((child, depth + 1) for child in children)


def too_deep(source: str, max_depth: int) -> str:
    """The message of a file that nests too deeply."""
    return f"{source}: nests lists and mappings deeper than {max_depth} levels (mapping.safe_parse.MAX_DEPTH)"


class BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader with a bound on nesting, duplicated keys refused and YAML 1.2's floats."""

    yaml_implicit_resolvers = {first: [(tag, pattern) for tag, pattern in resolvers if tag != FLOAT_TAG]
                               for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}

    def __init__(self, text: str, source: str = "<text>", max_depth: int = MAX_DEPTH):
        super().__init__(text)
        self.source, self.max_depth, self.depth = source, max_depth, 0

    def compose_node(self, parent, index):
        """Compose one node, refusing one nested deeper than ``max_depth`` before recursing into it."""
        self.depth += 1
        try:
            if self.depth > self.max_depth:
                raise ParseError(too_deep(self.source, self.max_depth))
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1

    def construct_mapping(self, node, deep=False):
        """A mapping, refusing a key given twice (merge keys ``<<`` may still be overridden)."""
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                duplicate = key in seen
                seen.add(key)
            except TypeError:  # an unhashable key: the base class says so
                continue
            if duplicate:
                raise ParseError(f"{self.source}: key {key!r} appears twice in one mapping "
                                 f"(line {key_node.start_mark.line + 1})")
        return super().construct_mapping(node, deep)


BoundedLoader.add_implicit_resolver(FLOAT_TAG, FLOAT_PATTERN, list("-+0123456789."))
