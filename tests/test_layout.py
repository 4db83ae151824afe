"""The architecture's rules (docs/architecture.md), checked on the source: imports point one way, no
module imports another's private names, no module grows past the size a reader takes in at once."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("mapping", "openmulti_env", "policies")
FORBIDDEN = {
    "mapping": ("openmulti_env", "policies", "studies", "benchmarks", "pettingzoo", "gymnasium", "pyrender",
                "supersuit", "stable_baselines3", "torchrl"),
    "openmulti_env": ("studies", "benchmarks"),
    "policies": ("mapping", "studies", "benchmarks"),
}
LAYOUT = "openmulti_env.environment.layout"
"""The env's observation contract: the one module of ``openmulti_env`` policies import."""
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


def under(module: str, *prefixes: str) -> bool:
    """Whether dotted ``module`` is one of ``prefixes`` or inside one."""
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def test_policies_import_of_the_env_only_its_observation_layout():
    """A policy sees observations and action spaces only: the env's layout names their parts, the rest of the
    env (and the simulator behind it) stays out of ``policies``."""
    wrong = [f"{path.relative_to(ROOT)}: {module} {names}" for path in modules("policies")
             for module, names in imports(path) if under(module, "openmulti_env") and module != LAYOUT]
    assert not wrong, f"policies may import of openmulti_env only {LAYOUT}:\n" + "\n".join(wrong)


def test_the_observation_layout_is_a_leaf():
    """``layout.py`` imports only numpy and the standard library (no relative imports either), and importing it
    (as every policy that reads observations does) loads neither the env, the world, the team nor torch."""
    path = ROOT / (LAYOUT.replace(".", "/") + ".py")
    tree = ast.parse(path.read_text(), str(path))
    relative = [node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.level]
    roots = {module.split(".")[0] for module, _ in imports(path)}
    assert not relative and roots <= set(sys.stdlib_module_names) | {"numpy"}, (relative, roots)
    heavy = ("openmulti_env.environment.parallel_env", "openmulti_env.world", "mapping", "torch", "pyrender")
    script = (f"import sys, {LAYOUT}, policies.novelty, policies.instance_novelty; "
              f"print([m for m in {heavy!r} if m in sys.modules])")
    loaded = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True,
                            cwd=ROOT).stdout.strip()
    assert loaded == "[]", f"importing the layout and the policies that read it loads {loaded}"


def test_world_imports_neither_the_pipeline_nor_the_team():
    """The world renders and plans paths; the run pipeline and the team sit above it (what it shares with them,
    ``mapping.figures`` and ``mapping.perception``, sits below)."""
    wrong = [f"{path.relative_to(ROOT)}: {module}" for path in (ROOT / "openmulti_env" / "world").rglob("*.py")
             for module, _ in imports(path) if under(module, "mapping.pipeline", "mapping.team")]
    assert not wrong, "openmulti_env/world must not import mapping.pipeline or mapping.team:\n" + "\n".join(wrong)


def test_env_imports_no_policies():
    """The env writes observations policies read; it never imports a policy (``runs`` wires the two together)."""
    wrong = [f"{path.relative_to(ROOT)}: {module}" for path in (ROOT / "openmulti_env" / "environment").rglob("*.py")
             for module, _ in imports(path) if under(module, "policies")]
    assert not wrong, "openmulti_env/environment must not import policies:\n" + "\n".join(wrong)


def part(module: str) -> str | None:
    """The part a dotted module belongs to in docs/architecture.md's pictures (None: not one of them)."""
    names = module.split(".")
    if under(module, LAYOUT):
        return "layout"
    if names[0] == "openmulti_env" and len(names) > 1:
        return "openmulti_v0.py" if names[1] == "openmulti_v0" else names[1]
    if names[0] == "mapping" and len(names) > 1:
        return f"mapping.{names[1]}" if (ROOT / "mapping" / names[1]).is_dir() else "mapping.utilities"
    return "policies" if names[0] == "policies" else None


def drawn_arrows() -> tuple[set[str], set[tuple[str, str]]]:
    """(parts, arrows) of the ``arrows`` blocks of docs/architecture.md: ``source -> target, mapping.{a, b}``,
    a line that starts with spaces continuing the one above."""
    parts, arrows = set(), set()
    for block in re.findall(r"```arrows\n(.*?)```", (ROOT / "docs" / "architecture.md").read_text(), re.S):
        for line in re.sub(r"\n\s+", " ", block).splitlines():
            source, _, targets = (s.strip() for s in line.partition("->"))
            targets = re.sub(r"([\w.]+)\.\{([^}]*)\}", lambda m: ", ".join(f"{m[1]}.{t.strip()}" for t in m[2].split(",")),
                             targets)
            parts.add(source)
            arrows |= {(source, target.strip()) for target in targets.split(",") if target.strip()}
    return parts, arrows


def test_the_pictures_draw_every_import_and_no_other():
    """docs/architecture.md's pictures of who imports whom: every import between two parts has its arrow, every
    arrow is an import, every part is drawn."""
    parts, drawn = drawn_arrows()
    found: dict[tuple[str, str], str] = {}
    existing = set()
    for path in (p for package in PACKAGES for p in modules(package)):
        source = part(".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__"))
        if source is None:
            continue
        existing.add(source)
        for module, _ in imports(path):
            if (target := part(module)) not in (None, source):
                found.setdefault((source, target), f"{path.relative_to(ROOT)}: {module}")
    missing = [f"  {s} -> {t}   e.g. {found[s, t]}" for s, t in sorted(set(found) - drawn)]
    extra = [f"  {s} -> {t}" for s, t in sorted(drawn - set(found))]
    assert parts == existing, f"parts drawn {sorted(parts - existing)} but not in the source; not drawn {sorted(existing - parts)}"
    assert not missing and not extra, ("docs/architecture.md (Who imports whom) must draw every import between its parts "
                                       "and no other;\nnot drawn:\n" + "\n".join(missing) + "\ndrawn, not imported:\n"
                                       + "\n".join(extra))


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
    assert loose == ["config_fields", "figures", "pointcloud", "runtime", "safe_parse"], \
        f"modules loose at mapping's root: {loose}"
