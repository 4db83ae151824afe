"""The index of studies and benchmarks in docs/benchmarks.md is what ``studies.index`` makes from the modules
today, and the two folders keep their rules: no ``sys.path`` edits, no private names imported, every entry
point says what it measures and where its figures are."""

from __future__ import annotations

import ast
from pathlib import Path

from studies import index

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted((ROOT / "studies").rglob("*.py")) + sorted((ROOT / "benchmarks").glob("*.py"))


def test_the_committed_index_is_todays():
    assert index.committed() == index.generated(), "docs/benchmarks.md is stale: run python -m studies.index --write"


def test_every_module_is_listed_once_and_every_entry_point_names_its_figures():
    studies, benchmarks = index.studies(), index.benchmarks()
    listed = {p.stem for p in (ROOT / "studies").glob("*.py")} - set(index.NOT_LISTED) | {"batch_alignment"}
    assert {e.name for e in studies} == listed
    assert {e.name for e in benchmarks} == {p.name for p in (ROOT / "benchmarks").glob("*.py")}
    for entry in studies + benchmarks:
        assert entry.summary, f"{entry.name}: no docstring"
        if entry.command:
            assert entry.figures, f"{entry.name}: no Figures: line in its docstring"
        for figure in entry.figures:
            assert figure.startswith("docs/") and (ROOT / figure.split("#")[0]).is_file(), (entry.name, figure)


def test_first_sentence_ends_at_a_sentence_not_an_abbreviation():
    assert index.first_sentence("Eq. 12 and eq. 13 variants: where? More.") == "Eq. 12 and eq. 13 variants: where?"
    assert index.first_sentence("Runs, grouped (e.g. Foo),\nkept on two lines. Then.") == \
        "Runs, grouped (e.g. Foo), kept on two lines."
    assert index.first_sentence("No full stop\n\nSecond paragraph.") == "No full stop"


def imports(path: Path) -> list[tuple[str, list[str]]]:
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name, []) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            found.append((node.module, [alias.name for alias in node.names]))
    return found


def test_no_sys_path_edits_and_no_private_names_imported():
    path_edits = [str(p.relative_to(ROOT)) for p in SOURCES if "sys.path" in p.read_text()]
    assert not path_edits, f"sys.path edited in {path_edits}: import installed packages instead"
    private = [f"{p.relative_to(ROOT)}: {module} {names}" for p in SOURCES for module, names in imports(p)
               if any(n.startswith("_") and not n.startswith("__") for n in names)
               or any(part.startswith("_") and not part.startswith("__") for part in module.split("."))]
    assert not private, "private names imported:\n" + "\n".join(private)


def test_benchmarks_are_scripts_and_studies_do_not_import_them():
    assert not (ROOT / "benchmarks" / "__init__.py").exists()
    wrong = [f"{p.relative_to(ROOT)}: {module}" for p in SOURCES for module, _ in imports(p)
             if module.split(".")[0] == "benchmarks"]
    assert not wrong, "benchmarks/ holds scripts, not a library:\n" + "\n".join(wrong)
