"""The layout of ``nnsf/`` (docs/architecture.md), read from the source with ``ast``.

* no import cycle between modules, and none between sub-packages;
* only the CLI imports the stage registry ``nnsf.stages`` (flows/ and the
  tests may too): no module below it depends on the set of stages;
* no module longer than 600 lines unless its docstring says why it is one
  concept;
* no import of a project module inside a function, except in the modules of
  :data:`DEFERRED_IMPORTS` (each with its reason): such imports hide the
  route from a reader and hid the cycles this test now forbids.
"""
from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "nnsf"
MAX_LINES = 600

#: Modules that may import project modules inside functions, and why.
DEFERRED_IMPORTS = {
    "nnsf": "`import nnsf.params` (run before every stage) must not pay for scikit-learn: "
            "nnsf.NNSF and nnsf.translate are loaded on first use",
    "nnsf.cli": "a command dispatcher: each command imports only its own code, so `nnsf check` "
                "and a bad argument answer at once",
}
#: Modules that may import the stage registry.
REGISTRY_USERS = {"nnsf.cli", "nnsf.stages"}


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _resolve(name: str) -> str | None:
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports(name: str, path: Path):
    """``(target module, node, inside a function)`` for every project import of a module."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    inside = set()
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            inside |= {id(n) for n in ast.walk(fn) if isinstance(n, (ast.Import, ast.ImportFrom))}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
        else:
            continue
        for target in targets:
            if target.split(".")[0] != "nnsf":
                continue
            resolved = _resolve(target)
            if resolved and resolved != name:
                yield resolved, node, id(node) in inside


EDGES = {name: {t for t, _, _ in _imports(name, path)} for name, path in MODULES.items()}


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan, iterative)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = 0
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(edges.get(w, ())))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        component.append(w)
                        if w == v:
                            break
                    if len(component) > 1:
                        out.append(sorted(component))
    return out


def test_the_cycle_finder_finds_a_cycle():
    """The oracle: a three-module ring and a two-module pair are found, a chain is not."""
    ring = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"e"}, "e": {"d"}, "f": {"a"}, "g": set()}
    assert sorted(_cycles(ring)) == [["a", "b", "c"], ["d", "e"]]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_no_import_cycle_between_modules():
    assert _cycles(EDGES) == []


def test_no_two_sub_packages_import_each_other():
    """Sub-packages (folders of nnsf/) form a layered graph: a cycle among them is a tangle."""
    packages = {name for name, path in MODULES.items() if path.name == "__init__.py" and name != "nnsf"}

    def package(module):
        parts = module.split(".")
        return ".".join(parts[:2]) if ".".join(parts[:2]) in packages else None

    edges = defaultdict(set)
    for source, targets in EDGES.items():
        for target in targets:
            a, b = package(source), package(target)
            if a and b and a != b:
                edges[a].add(b)
    assert _cycles(dict(edges)) == []


def test_only_the_cli_imports_the_stage_registry():
    users = {name for name, targets in EDGES.items() if "nnsf.stages" in targets}
    assert users <= REGISTRY_USERS, f"nnsf.stages imported by {sorted(users - REGISTRY_USERS)}"


def test_no_project_import_inside_a_function():
    found = [f"{MODULES[name].relative_to(PACKAGE.parent)}:{node.lineno} imports {target}"
             for name, path in MODULES.items() if name not in DEFERRED_IMPORTS
             for target, node, inside in _imports(name, path) if inside]
    assert found == []


def test_stage_names_are_defined_once_and_every_stage_is_registered():
    """dvc.yaml's stages are nnsf.params.STAGE_NAMES, and the registry runs each (sweep by its points)."""
    import yaml

    from nnsf.params import STAGE_NAMES
    from nnsf.stages import REGISTRY, get

    dvc = yaml.safe_load((PACKAGE.parent / "dvc.yaml").read_text())
    assert tuple(dvc["stages"]) == STAGE_NAMES
    assert set(STAGE_NAMES) - {"sweep"} | {"sweep_grid", "sweep_point"} == set(REGISTRY)
    for name in REGISTRY:
        assert callable(get(name))


@pytest.mark.parametrize("name", sorted(MODULES))
def test_module_is_at_most_600_lines_or_says_why_it_is_one_concept(name):
    path = MODULES[name]
    lines = len(path.read_text().splitlines())
    if lines <= MAX_LINES:
        return
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    assert "one concept" in doc.lower(), (
        f"{path.relative_to(PACKAGE.parent)} has {lines} lines (> {MAX_LINES}) and its docstring "
        "does not say why it is one concept")
