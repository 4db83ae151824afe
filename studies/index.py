"""The index of studies and timing benchmarks in docs/benchmarks.md, made from the modules' own docstrings so
that it cannot drift from the code.

Each row is a module's name, the first sentence of its docstring, the command that runs it and the pages its
figures are quoted on (the docstring's ``Figures:`` line, paths under ``docs/``). The sources are read, not
imported: listing the studies loads neither torch nor a world.

    python -m studies.index            # print the tables
    python -m studies.index --write    # put them between the markers of docs/benchmarks.md
    python -m studies.index --check    # exit 1 when docs/benchmarks.md's tables are not today's
"""

from __future__ import annotations

import argparse
import ast
import re
from dataclasses import dataclass
from pathlib import Path

STUDIES = Path(__file__).resolve().parent
ROOT = STUDIES.parent
BENCHMARKS = ROOT / "benchmarks"
DOC = ROOT / "docs" / "benchmarks.md"
START, END = "<!-- index:start -->", "<!-- index:end -->"
NOTE = "<!-- made by `python -m studies.index --write` from the modules' docstrings: edit those, not these tables -->"
NOT_LISTED = ("__init__", "index")
ABBREVIATIONS = ("e.g", "i.e", "eq", "cf", "vs", "fig", "sec")
"""A full stop after these ends no sentence."""


@dataclass(frozen=True)
class Entry:
    """One module of the index: what its docstring says and how to run it (None: a module the studies share)."""

    name: str
    summary: str
    command: str | None
    figures: tuple[str, ...]


def first_sentence(doc: str) -> str:
    """The docstring's first sentence (of its first paragraph, lines joined): up to the first ``.``, ``?`` or
    ``!`` that a space and a capital, a backtick or a bracket follow, abbreviations aside."""
    paragraph = " ".join(doc.strip().split("\n\n")[0].split())
    for match in re.finditer(r"[.?!](?=\s+[A-Z`(\[])", paragraph):
        words = paragraph[:match.start()].split()
        if match.group() == "." and words and words[-1].lower().lstrip("([`") in ABBREVIATIONS:
            continue
        return paragraph[:match.end()]
    return paragraph


def figures(doc: str) -> tuple[str, ...]:
    """The docstring's ``Figures:`` line as paths under docs/ (``docs/world.md#measured``)."""
    found = re.search(r"^Figures:\s*(.+)$", doc, re.M)
    return tuple(part.strip() for part in found.group(1).split(",")) if found else ()


def runnable(tree: ast.Module) -> bool:
    """Whether the module ends in ``if __name__ == "__main__":`` (an entry point, not a library module)."""
    return any(isinstance(node, ast.If) and isinstance(node.test, ast.Compare)
               and isinstance(node.test.left, ast.Name) and node.test.left.id == "__name__" for node in tree.body)


def entry(path: Path, name: str, command: str) -> Entry:
    """``path``'s entry, read from its source (a package: its ``__init__.py``)."""
    source = path / "__init__.py" if path.is_dir() else path
    tree = ast.parse(source.read_text(), str(source))
    doc = ast.get_docstring(tree) or ""
    return Entry(name, first_sentence(doc), command if runnable(tree) else None, figures(doc))


def studies() -> list[Entry]:
    """Every module and sub-package of ``studies`` but this one, by name."""
    paths = sorted(p for p in STUDIES.iterdir()
                   if (p.suffix == ".py" and p.stem not in NOT_LISTED) or (p / "__init__.py").is_file())
    return [entry(p, p.stem, f"python -m studies.{p.stem}") for p in paths]


def benchmarks() -> list[Entry]:
    """Every script of ``benchmarks/``, by name (none when the package was installed without the repository)."""
    paths = sorted(BENCHMARKS.glob("*.py")) if BENCHMARKS.is_dir() else []
    return [entry(p, p.name, f"python benchmarks/{p.name}") for p in paths]


def cell(text: str) -> str:
    return text.replace("|", "\\|")


def links(paths: tuple[str, ...]) -> str:
    """``docs/world.md#measured`` -> ``[world.md](world.md#measured)``: links from docs/benchmarks.md."""
    out = []
    for path in paths:
        target = path.removeprefix("docs/")
        out.append(f"[{target.split('#')[0]}]({target})")
    return ", ".join(out)


def tables(study_entries: list[Entry], benchmark_entries: list[Entry]) -> str:
    """The Markdown between the markers: studies, timing benchmarks, the modules the studies share."""
    lines = [NOTE, "", "Studies (what a choice is worth; result rows), from any folder once the package is installed:",
             "", "| command | what it measures | figures |", "|---|---|---|"]
    lines += [f"| `{e.command}` | {cell(e.summary)} | {links(e.figures)} |" for e in study_entries if e.command]
    lines += ["", "Timing benchmarks (speed, memory, profiles), from the repository's root:", "",
              "| command | what it measures | figures |", "|---|---|---|"]
    lines += [f"| `{e.command}` | {cell(e.summary)} | {links(e.figures)} |" for e in benchmark_entries if e.command]
    lines += ["", "Modules the studies share (tested in `tests/test_studies_*.py`):", "",
              "| module | what it holds |", "|---|---|"]
    lines += [f"| `studies.{e.name}` | {cell(e.summary)} |" for e in study_entries if not e.command]
    return "\n".join(lines) + "\n"


def generated() -> str:
    """Today's tables."""
    return tables(studies(), benchmarks())


def committed(doc: Path = DOC) -> str:
    """The tables between the markers of ``doc``."""
    text = doc.read_text()
    if text.count(START) != 1 or text.count(END) != 1:
        raise ValueError(f"{doc}: expected one {START} and one {END}")
    return text.split(START, 1)[1].split(END, 1)[0].removeprefix("\n")


def write(doc: Path = DOC) -> bool:
    """Put today's tables between the markers of ``doc``; whether anything changed."""
    text = doc.read_text()
    new = text.replace(START + "\n" + committed(doc) + END, START + "\n" + generated() + END)
    if new != text:
        doc.write_text(new)
    return new != text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    action = parser.add_mutually_exclusive_group()
    action.add_argument("--write", action="store_true", help=f"replace the tables in {DOC.relative_to(ROOT)}")
    action.add_argument("--check", action="store_true", help="exit 1 when the committed tables are stale")
    args = parser.parse_args(argv)
    if args.write:
        print(f"{DOC.relative_to(ROOT)}: {'updated' if write() else 'already up to date'}")
    elif args.check:
        if committed() != generated():
            print(f"{DOC.relative_to(ROOT)}: the index is stale; run python -m studies.index --write")
            return 1
    else:
        print(generated(), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
