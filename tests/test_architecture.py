"""The layout of ``nnsf/`` (docs/architecture.md), read from the source with ``ast``.

* no import cycle between modules, and none between sub-packages;
* only the CLI imports the stage registry ``nnsf.stages`` (flows/ and the
  tests may too): no module below it depends on the set of stages;
* no private name (``_x``) of one module used by another, by import or as a
  module attribute: a name another module needs is part of its module's
  interface and is named as such; a module split in two along a line that
  cuts through its private helpers is split in the wrong place (the pairs of
  :data:`SHARED_PRIVATE` are listed with their reason);
* no import of a project module inside a function, except in the modules of
  :data:`DEFERRED_IMPORTS` (each with its reason): such imports hide the
  route from a reader, and the cycles the first rule forbids.

Module length is not a rule: a module is one concept, however long.
"""
from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "nnsf"

#: Modules that may import project modules inside functions, and why.
DEFERRED_IMPORTS = {
    "nnsf": "`import nnsf.params` (run before every stage) must not pay for scikit-learn: "
            "nnsf.NNSF and nnsf.translate are loaded on first use",
    "nnsf.cli": "a command dispatcher: each command imports only its own code, so `nnsf check` "
                "and a bad argument answer at once",
}
#: Modules that may import the stage registry.
REGISTRY_USERS = {"nnsf.cli", "nnsf.stages"}
#: Private names one module uses of another: (user, owner) -> (names, why).  Each is a helper
#: shared inside one sub-package; an entry that no longer occurs fails
#: test_shared_private_names_are_still_used, so the list only shrinks.
SHARED_PRIVATE: dict[tuple[str, str], tuple[tuple[str, ...], str]] = {
    ("nnsf.evaluate.heldout_bvh", "nnsf.evaluate.heldout_report"): (
        ("_target_check",), "the held-out targets, checked by both report writers"),
    ("nnsf.evaluate.heldout_bvh", "nnsf.evaluate.translation"): (
        ("_pick",), "row selection of the held-out protocol, shared by its report writers"),
    ("nnsf.evaluate.heldout_report", "nnsf.evaluate.translation"): (
        ("_pick",), "row selection of the held-out protocol, shared by its report writers"),
    ("nnsf.evaluate.translation", "nnsf.evaluate.scores"): (
        ("_unify",), "the protocol's scoring steps, applied per cell"),
    ("nnsf.factor.align", "nnsf.factor.updates"): (
        ("_basis_step",), "NNSF's basis step (Alg. 1, lines 1-3), reused by the aligned fit"),
    ("nnsf.factor.translate", "nnsf.factor.updates"): (
        ("_basis_step",), "NNSF's basis step (Alg. 1, lines 1-3), reused by the translator's fit"),
    ("nnsf.factor.translate", "nnsf.factor.timewarp"): (
        ("_style_tempo",), "a style's tempo, read by the translator"),
}


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


def _private_uses(name: str, path: Path):
    """``(owner module, private name, line)`` of every private name of another project module
    that ``name`` imports (``from m import _x``) or reads off an imported module (``m._x``)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    modules: dict[str, str] = {}  # local name -> project module
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            if base.split(".")[0] != "nnsf":
                continue
            for alias in node.names:
                if f"{base}.{alias.name}" in MODULES:
                    modules[alias.asname or alias.name] = f"{base}.{alias.name}"
                elif _private(alias.name) and _resolve(base) != name:
                    yield _resolve(base), alias.name, node.lineno
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "nnsf" and alias.asname:
                    modules[alias.asname] = alias.name
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and _private(node.attr)
                and modules.get(node.value.id, name) != name):
            yield modules[node.value.id], node.attr, node.lineno


def _private(identifier: str) -> bool:
    return identifier.startswith("_") and not identifier.startswith("__")


PRIVATE_USES = {(name, owner, attr): line for name, path in MODULES.items()
                for owner, attr, line in _private_uses(name, path)}


def test_the_private_name_finder_finds_imports_and_attributes(tmp_path, monkeypatch):
    """The oracle: both spellings of a cross-module private use are found; a module's own
    private names, dunders and public names are not."""
    user = tmp_path / "user.py"
    user.write_text("from nnsf.io import _hidden, atomic_path\nfrom nnsf import io\n"
                    "import nnsf.params as P\nio._other()\nP._x\nio.__name__\n")
    found = sorted((owner, attr) for owner, attr, _ in _private_uses("nnsf.user", user))
    assert found == [("nnsf.io", "_hidden"), ("nnsf.io", "_other"), ("nnsf.params", "_x")]
    own = tmp_path / "own.py"
    own.write_text("from nnsf.io import _hidden\n")
    assert list(_private_uses("nnsf.io", own)) == []


def test_no_module_uses_another_modules_private_names():
    allowed = {(user, owner, attr) for (user, owner), (names, _) in SHARED_PRIVATE.items() for attr in names}
    found = [f"{MODULES[user].relative_to(PACKAGE.parent)}:{line} uses {owner}.{attr}"
             for (user, owner, attr), line in sorted(PRIVATE_USES.items())
             if (user, owner, attr) not in allowed]
    assert found == [], "name it as part of its module's interface (no leading underscore)"


def test_shared_private_names_are_still_used():
    stale = [f"{user} -> {owner}.{attr}" for (user, owner), (names, _) in SHARED_PRIVATE.items()
             for attr in names if (user, owner, attr) not in PRIVATE_USES]
    assert stale == [], "remove these from SHARED_PRIVATE"
