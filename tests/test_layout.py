"""The architecture's rules (docs/architecture.md), checked on the source: imports point one way, no
module imports another's private names, no module grows past the size a reader takes in at once."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("mapping", "openmulti_env", "policies")
FORBIDDEN = {
    "mapping": ("openmulti_env", "policies", "benchmarks", "pettingzoo", "gymnasium", "pyrender", "supersuit",
                "stable_baselines3", "torchrl"),
    "openmulti_env": ("benchmarks",),
    "policies": ("openmulti_env", "mapping", "benchmarks"),
}
MAX_LINES = 420
"""About 400 lines at most per module."""


def modules(package: str) -> list[Path]:
    return sorted(p for p in (ROOT / package).rglob("*.py") if "__pycache__" not in p.parts)


def imports(path: Path) -> list[tuple[str, list[str]]]:
    """(module, imported names) of every absolute import in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name, []) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.module, [alias.name for alias in node.names]))
    return found


@pytest.mark.parametrize("package", PACKAGES)
def test_imports_point_one_way(package: str):
    wrong = [f"{path.relative_to(ROOT)}: {module}" for path in modules(package) for module, _ in imports(path)
             if module.split(".")[0] in FORBIDDEN[package]]
    assert not wrong, f"{package} must not import {FORBIDDEN[package]}:\n" + "\n".join(wrong)


@pytest.mark.parametrize("package", PACKAGES)
def test_no_module_imports_another_modules_private_names(package: str):
    wrong = []
    for path in modules(package):
        for module, names in imports(path):
            if module.split(".")[0] not in PACKAGES:
                continue
            private = [n for n in names if n.startswith("_") and not n.startswith("__")]
            private_module = [p for p in module.split(".") if p.startswith("_") and not p.startswith("__")]
            if private or private_module:
                wrong.append(f"{path.relative_to(ROOT)}: from {module} import {', '.join(names)}")
    assert not wrong, "private names imported across modules:\n" + "\n".join(wrong)


@pytest.mark.parametrize("package", PACKAGES)
def test_modules_stay_small(package: str):
    big = {str(p.relative_to(ROOT)): n for p in modules(package) if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not big, f"modules over {MAX_LINES} lines (split them by job): {big}"


def subpackage_graph(package: str):
    """Which sub-package of ``package`` imports which (a module at its root counts as a sub-package of its own
    name), from every import in the source, function-level ones included."""
    import networkx as nx  # noqa: PLC0415

    graph = nx.DiGraph()
    for path in modules(package):
        parts = path.relative_to(ROOT / package).with_suffix("").parts
        source = parts[0]
        if source == "__init__":
            continue
        graph.add_node(source)
        for module, _ in imports(path):
            target = module.split(".")
            if target[0] == package and len(target) > 1 and target[1] != source:
                graph.add_edge(source, target[1], example=f"{path.relative_to(ROOT)} -> {module}")
    return graph


def test_mapping_subpackages_import_without_cycles():
    """``mapping``'s parts stack: data and perception under fusion, alignment and the model, the team on those,
    the pipeline and evaluation on top; no two parts import each other through any path."""
    import networkx as nx  # noqa: PLC0415

    graph = subpackage_graph("mapping")
    cycles = list(nx.simple_cycles(graph))
    described = ["  " + " -> ".join(c + [c[0]]) + "   e.g. " + "; ".join(
        graph.edges[a, b]["example"] for a, b in zip(c, c[1:] + c[:1])) for c in cycles[:5]]
    assert not cycles, f"{len(cycles)} import cycle(s) between mapping's sub-packages:\n" + "\n".join(described)


def test_mapping_keeps_its_model_in_a_subpackage():
    loose = sorted(p.stem for p in (ROOT / "mapping").glob("*.py") if p.stem != "__init__")
    assert loose == ["config_fields", "pointcloud", "runtime", "safe_parse"], f"modules loose at mapping's root: {loose}"
