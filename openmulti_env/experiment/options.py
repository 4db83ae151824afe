"""The command line generated from a dataclass tree: one ``--node.field`` option per field (help from the
field's docstring, the value a preset gives beside it), grouped by node, plus the short spellings
(``--scene``, ``--no-cross-rendering``, ...) that name a field of the tree.

Why argparse built from the fields rather than tyro or jsonargparse: the ``openmulti`` command has six
subcommands whose other options (``query``, ``reproduce``, ``scenes``) are no tree, its presets choose the
defaults only after parsing (``--preset`` is itself an option), and the short spellings of the README must keep
working beside the generated ones; a hundred lines here keep all of that in one parser with no new dependency.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import textwrap
import typing
from functools import lru_cache
from typing import Any, Mapping

from mapping.safe_parse import ParseError, parse_yaml
from openmulti_env.experiment.overrides import ALIASES, ConfigError, field_types

TRAIN_DEST = "train:"
"""Prefix of the namespace attributes that hold ``TrainConfig`` fields."""
TREE_DEST = "tree:"
"""Prefix of the namespace attributes that hold tree overrides (``tree:team.exchange.float16``)."""

FLAGS: dict[str, tuple[str, Any]] = {
    "no_cross_rendering": ("team.consistency.cross_rendering", False),
    "no_evaluation": ("run.evaluate", False),
}
"""Short flags of the older command line: the field each one sets and the value it sets it to."""
SHORT_METAVARS = {"alignment": "{paper,none}", "out": "DIR", "data": "DIR", "gt_mesh": "PLY", "frames": "A:B:S",
                  "intrinsics": "FX,FY,CX,CY", "comm_budget_mb": "MB", "holdout_every": "K",
                  "link_range_m": "M", "link_mb_per_round": "MB"}


@lru_cache(maxsize=None)
def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of a dataclass (the string right after its annotation)."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError):
        return {}
    body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
    docs = {}
    for node, after in zip(body, body[1:]):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str)):
            docs[node.target.id] = " ".join(after.value.value.split()).replace("%", "%%")  # argparse formats help
    return docs


def tree_fields(cls: type, prefix: str = "") -> list[tuple[str, Any, str, type]]:
    """Every leaf of the tree under ``cls``: (dotted path, type, docstring, the class that holds it)."""
    out = []
    for f in dataclasses.fields(cls):
        kind = field_types(cls)[f.name]
        if dataclasses.is_dataclass(kind):
            out += tree_fields(kind, f"{prefix}{f.name}.")
        else:
            out.append((prefix + f.name, kind, field_docs(cls).get(f.name, ""), cls))
    return out


def value_at(tree, path: str):
    for part in path.split("."):
        tree = getattr(tree, part)
    return tree


def add_tree_options(parser: argparse.ArgumentParser, root: type, shown=None, short: tuple[str, ...] = (),
                     skip: tuple[str, ...] = ()) -> None:
    """Add ``--path.to.field`` for every leaf of ``root`` (``shown``: a tree whose values the help quotes,
    e.g. a preset), grouped by node, and ``--NAME`` for each short spelling in ``short`` (``ALIASES`` or
    ``FLAGS``). Their values land in the namespace under ``TREE_DEST + path`` (``tree_overrides`` reads them)."""
    docs = {path: (kind, doc) for path, kind, doc, _ in tree_fields(root)}
    if short:
        group = parser.add_argument_group("common settings (short spellings of the tree's fields below)")
        for name in short:
            if name in FLAGS:
                path, value = FLAGS[name]
                group.add_argument("--" + name.replace("_", "-"), dest=TREE_DEST + path, action="store_const",
                                   const=value, default=argparse.SUPPRESS,
                                   help=f"{path} = {value}: {docs[path][1]}")
            else:
                path = ALIASES.get(name, name)
                kind, doc = docs[path]
                same = "" if path == name else f" (= --{_spelled(path)})"
                group.add_argument("--" + name.replace("_", "-"), dest=TREE_DEST + path, default=argparse.SUPPRESS,
                                   metavar=SHORT_METAVARS.get(name, _metavar(kind)), help=doc + same)
    groups: dict[str, argparse._ArgumentGroup] = {}
    for path, kind, doc, holder in tree_fields(root):
        if path in skip or any(path.startswith(s + ".") for s in skip) or path in short:
            continue  # (a top-level field with a short spelling is that spelling)
        node = path.rsplit(".", 1)[0] if "." in path else ""
        if node not in groups:
            title = f"{node} ({holder.__name__})" if node else root.__name__
            summary = (inspect.getdoc(holder) or "").split("\n")[0]
            groups[node] = parser.add_argument_group(title, summary)
        said = "" if shown is None else f" ({getattr(shown, 'preset', 'default')}: {_shown(value_at(shown, path))})"
        bool_flag = kind is bool
        groups[node].add_argument("--" + _spelled(path), dest=TREE_DEST + path, default=argparse.SUPPRESS,
                                  nargs="?" if bool_flag else None, const="true" if bool_flag else None,
                                  metavar=_metavar(kind), help=(doc or path) + said)


def tree_overrides(args: argparse.Namespace, prefix: str = TREE_DEST) -> dict[str, Any]:
    """The overrides the command line gave under ``prefix``: dotted path -> the string as given
    (``typed_overrides`` reads them)."""
    return {dest[len(prefix):]: raw for dest, raw in vars(args).items() if dest.startswith(prefix)}


def add_dataclass_options(parser: argparse.ArgumentParser, cls: type, prefix: str, title: str,
                          also: dict[str, str] | None = None) -> None:
    """``--field`` for each field of a flat dataclass (``policies.train.TrainConfig``), its docstring as help
    and its default shown, stored under ``prefix + field`` (``also``: other spellings, name -> field)."""
    group = parser.add_argument_group(title)
    defaults, docs = cls(), field_docs(cls)
    for f in dataclasses.fields(cls):
        spellings = ["--" + f.name.replace("_", "-")] + ["--" + k.replace("_", "-") for k, v in (also or {}).items()
                                                          if v == f.name]
        kind = field_types(cls)[f.name]
        group.add_argument(*spellings, dest=prefix + f.name, default=argparse.SUPPRESS, metavar=_metavar(kind),
                           help=f"{docs.get(f.name, f.name)} (default: {_shown(getattr(defaults, f.name))})")


def parse_value(raw: Any, kind) -> Any:
    """A command-line string as the value a field of ``kind`` takes (the tree then checks it)."""
    if not isinstance(raw, str):
        return raw
    args = typing.get_args(kind)
    may_be_none = type(None) in args
    if may_be_none and raw.lower() in ("none", "null"):
        return None
    plain = [a for a in args if a is not type(None)] or [kind]
    if str in plain or kind is str:
        return raw
    try:
        return parse_yaml(raw, f"the value {raw!r}")  # YAML 1.2's numbers: 1e12 and 1E-3 are numbers
    except ParseError as exc:
        raise ConfigError(f"cannot read {raw!r}: {exc}") from None


def typed_overrides(overrides: dict[str, Any], root: type) -> dict[str, Any]:
    """``tree_overrides`` with each string read for its field's type (``parse_value``)."""
    kinds = {path: kind for path, kind, _, _ in tree_fields(root)}
    return {path: parse_value(raw, kinds.get(path, str)) for path, raw in overrides.items()}


def normalise_argv(argv: list[str]) -> list[str]:
    """``--team.exchange.changed_only`` spelled with dashes (``--team.exchange.changed-only``), as the parser
    knows it."""
    out = []
    for token in argv:
        if token.startswith("--") and "." in token.split("=", 1)[0]:
            name, eq, value = token.partition("=")
            token = name.replace("_", "-") + eq + value
        out.append(token)
    return out


def spelled_for_command_line(message: str, options: Mapping[str, Any]) -> str:
    """``message`` (a ConfigError's) with its leading field path spelled as the option that sets it on this
    command line, e.g. ``--comm-budget-mb (channel.budget_mb) must be >= 0``: the user reads what they typed."""
    path, _, rest = message.partition(" ")
    for name in (name for name, target in ALIASES.items() if target == path):
        option = "--" + _spelled(name)
        if option in options:
            return f"{option} ({path}) {rest}"
    return message


def _spelled(path: str) -> str:
    return path.replace("_", "-")


def _metavar(kind) -> str:
    args = [a for a in typing.get_args(kind) if a is not type(None)] or [kind]
    base = args[0]
    if base is bool:
        return "BOOL"
    if typing.get_origin(base) is tuple or dataclasses.is_dataclass(base):
        return "YAML"
    return {int: "INT", float: "X", str: "TEXT"}.get(base, "VALUE")


def _shown(value) -> str:
    if dataclasses.is_dataclass(value):
        return "set"
    return "none" if value is None else str(value).lower() if isinstance(value, bool) else str(value)
