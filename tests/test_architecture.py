"""The package's import structure: layers, no circles, and a reason for every function-local import.

Every module of ``d5rl`` is parsed with ``ast`` and every import counts, also those inside functions:
a lazy import is a dependency all the same, only paid later.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "d5rl"

# The floors, lowest first: a module may import modules of its own floor or of a lower one, never of a
# higher one (and circles are refused below, so two units of one floor depend on each other one way only).
# A unit is a sub-package (``d5rl.envs``) or a top-level module (``d5rl.errors``); ``d5rl`` is the package's
# facade (``d5rl.make``), on the top floor.  Plug-ins named by strings (a task's ``entry_point``, a
# dataset's ``generator``, resolved by ``d5rl.registry.resolve``) are not imports: that is how the lower
# floors reach code above them without depending on it.
FLOORS = (
    # foundations: errors, file and path helpers, numerics, assets, the task registry, the GL backend choice
    (
        "d5rl.errors",
        "d5rl.paths",
        "d5rl.gl",
        "d5rl.xla_flags",
        "d5rl.progress",
        "d5rl.files",
        "d5rl.numerics",
        "d5rl.assets",
        "d5rl.registry",
        "d5rl.version",
        "d5rl.rollout",  # the one rollout loop: numpy and Gymnasium only
    ),
    ("d5rl.rendering", "d5rl.video"),  # offscreen rendering and video files
    ("d5rl.envs",),  # simulation: models, tasks, registration
    ("d5rl.parallel",),  # the executor (local processes or Ray)
    ("d5rl.datasets",),  # the dataset format: writing, loading, checking, exporting
    ("d5rl.agents",),  # the offline RL algorithms
    ("d5rl.training", "d5rl.settings"),  # training runs and their settings
    ("d5rl.production",),  # data production: generators, data agents, data-card statistics
    ("d5rl.runner", "d5rl.browse", "d5rl.cli", "d5rl"),  # benchmarks, reports, the dataset browser, the CLI
)
FLOOR = {unit: i for i, units in enumerate(FLOORS) for unit in units}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _is_package(module: str) -> bool:
    return MODULES[module].name == "__init__.py"


def _unit(module: str) -> str:
    """``d5rl.envs.a1.task`` -> ``d5rl.envs``; ``d5rl.errors`` -> ``d5rl.errors``; ``d5rl`` -> ``d5rl``."""
    return ".".join(module.split(".")[:2])


def _folder(module: str, depth: int) -> str:
    """The folder a module lies in, at most ``depth`` names deep; a top-level module is its own folder."""
    parts = module.split(".")
    pkg = parts if _is_package(module) else parts[:-1]
    return module if len(pkg) <= 1 else ".".join(pkg[:depth])


class Import:
    def __init__(self, source: str, target: str, line: int, local: bool, commented: bool):
        self.source, self.target, self.line, self.local, self.commented = source, target, line, local, commented

    def __repr__(self) -> str:
        return f"{self.source}:{self.line} -> {self.target}"


def _imports(module: str) -> list[Import]:
    """Every import of a d5rl module in ``module``, with whether it is inside a function and commented."""
    path = MODULES[module]
    text = path.read_text()
    lines = text.splitlines()
    tree = ast.parse(text)
    pkg = module.split(".") if _is_package(module) else module.split(".")[:-1]
    out: list[Import] = []

    def visit(node: ast.AST, local: bool) -> None:
        block_said = False  # a comment above a block of imports speaks for the whole block
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                visit(child, True)
                continue
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                above = lines[child.lineno - 2].strip() if child.lineno > 1 else ""
                in_block = above.startswith(("from ", "import ")) or (above.startswith(")") and block_said)
                said = (block_said and in_block) or above.startswith("#")
                said = said or any("#" in s for s in lines[child.lineno - 1 : child.end_lineno])
                block_said = said
            targets = []
            if isinstance(child, ast.Import):
                targets = [a.name for a in child.names]
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    base = ".".join(pkg[: len(pkg) - child.level + 1] + ([base] if base else []))
                # ``from d5rl.envs.a1 import rewards`` imports the module d5rl.envs.a1.rewards
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in child.names]
            for t in dict.fromkeys(targets):
                if t == "d5rl" or t.startswith("d5rl."):
                    while t not in MODULES:  # ``import d5rl.envs.a1.task as x`` etc.: the longest known module
                        t = t.rpartition(".")[0]
                    out.append(Import(module, t, child.lineno, local, said))
            visit(child, local)

    visit(tree, False)
    return out


IMPORTS = [imp for module in MODULES for imp in _imports(module)]


def _cycles(edges: set[tuple[str, str]]) -> list[list[str]]:
    """The strongly connected components with more than one node (Tarjan)."""
    graph: dict[str, set[str]] = {}
    for a, b in edges:
        if a != b:
            graph.setdefault(a, set()).add(b)
            graph.setdefault(b, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def strongconnect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                strongconnect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strongconnect(v)
    return sorted(found)


def test_every_unit_has_a_floor():
    assert sorted({_unit(m) for m in MODULES} - set(FLOOR)) == []


def test_imports_run_down_the_floors():
    upward = [
        f"{imp} ({_unit(imp.source)} floor {FLOOR[_unit(imp.source)]} -> {_unit(imp.target)} "
        f"floor {FLOOR[_unit(imp.target)]})"
        for imp in IMPORTS
        if FLOOR[_unit(imp.target)] > FLOOR[_unit(imp.source)]
    ]
    assert upward == []


@pytest.mark.parametrize("level", ["file", "unit", "family"])
def test_no_import_circles(level):
    key = {"file": lambda m: m, "unit": _unit, "family": lambda m: _folder(m, 3)}[level]
    assert _cycles({(key(i.source), key(i.target)) for i in IMPORTS}) == []


def test_function_local_imports_say_why():
    """A function-local import is for an optional dependency or for start-up time, and its comment says so."""
    silent = [repr(i) for i in IMPORTS if i.local and not i.commented]
    assert silent == []


def test_the_checks_can_fail():
    """The cycle finder sees a circle through three nodes and none in a chain; units and folders."""
    assert _cycles({("a", "b"), ("b", "c"), ("c", "a"), ("c", "d")}) == [["a", "b", "c"]]
    assert _cycles({("a", "b"), ("b", "c")}) == []
    assert _unit("d5rl.envs.a1.task") == "d5rl.envs" and _unit("d5rl.errors") == "d5rl.errors"
    assert _folder("d5rl.envs.kitchen.randomized.task", 3) == "d5rl.envs.kitchen"
    assert _folder("d5rl.envs.base", 3) == "d5rl.envs" and _folder("d5rl.errors", 3) == "d5rl.errors"
