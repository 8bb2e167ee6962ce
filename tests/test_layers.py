"""The package's layers (docs/architecture.md) checked over the code's own imports.

Every module of `omnibench` is parsed (ast); every import in it counts, at the top or inside a
function, and so does a string constant that names an omnibench module (what importlib loads).
An import may point to its own layer unit or to a lower layer, never up and never sideways to
another unit of the same layer; no two packages (sub-packages included) import each other
through any chain; and no module imports another module's private (`_name`) names.
"""

from __future__ import annotations

import ast
import functools
from collections import defaultdict
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "omnibench"

#: The layers, lowest first, as in docs/architecture.md. A unit is a sub-package of omnibench
#: (its first name after `omnibench.`); "base" is the root package's own small modules.
#: Units in the same layer know nothing of each other.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("base",),                                   # omnibench/__init__, errors, files, resources, locks, progress
    ("model",),                                  # the physics
    ("effects",),                                # candidate effects registered into the model's terms
    ("worlds", "link", "procedures", "runs"),    # test physics, bytes on a port, plans, run directories
    ("sim", "bench", "analysis"),                # the simulated board, the bench, the analysis
    ("campaign",),                               # campaigns: bench then analysis, reports
    ("cli",),                                    # the command line (and `python -m omnibench`)
)
BASE = {"omnibench", "omnibench.errors", "omnibench.files", "omnibench.resources", "omnibench.locks",
        "omnibench.progress"}
RANK = {unit: k for k, layer in enumerate(LAYERS) for unit in layer}

#: Imports allowed against the layers, each with its reason. Add none.
EXCEPTIONS: dict[tuple[str, str], str] = {
    # pyserial's URL-handler registry is by package name: link/urls.py appends "omnibench.sim" to
    # serial.protocol_handler_packages and pyserial imports sim's `protocol_sim` when a sim:// URL is
    # opened. No import of the simulator in the link's code; the name is the plugin's registration.
    ("omnibench.link.urls", "omnibench.sim"): "pyserial URL handler",
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


@functools.cache
def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


@functools.cache
def _packages() -> frozenset[str]:
    return frozenset(_module_name(p) for p in PACKAGE.rglob("__init__.py"))


def _imports(name: str, path: Path) -> list[tuple[str, int]]:
    """(imported omnibench module, line) for every import in the module, function-local included."""
    is_pkg = path.name == "__init__.py"
    here = name if is_pkg else name.rsplit(".", 1)[0]
    found: list[tuple[str, int]] = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here.split(".")[: len(here.split(".")) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            for a in node.names:  # `from pkg import module` imports the module
                sub = f"{mod}.{a.name}"
                found.append((sub if sub in _modules() else mod, node.lineno))
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in _modules():
            found.append((node.value, node.lineno))  # importlib.import_module("omnibench....")
    return [(m, line) for m, line in found if m == "omnibench" or m.startswith("omnibench.")]


#: Private names (`_x`) imported from another module, each with its reason. Add none.
PRIVATE_EXCEPTIONS: dict[tuple[str, str], str] = {}


def _unit(module: str) -> str:
    if module in BASE:
        return "base"
    if module == "omnibench.__main__":
        return "cli"
    return module.split(".")[1]


def _package(module: str) -> str:
    while module not in _packages():
        module = module.rsplit(".", 1)[0]
    return module


def test_every_unit_has_a_layer() -> None:
    units = {_unit(m) for m in _modules()}
    assert units <= set(RANK), f"packages missing from LAYERS (and docs/architecture.md): {units - set(RANK)}"


def test_no_import_points_up_or_sideways() -> None:
    bad, used = [], set()
    for name, path in _modules().items():
        src = _unit(name)
        for target, line in _imports(name, path):
            dst = _unit(target)
            if dst == src or RANK[dst] < RANK[src]:
                continue
            key = (name, target)
            if key in EXCEPTIONS:
                used.add(key)
                continue
            bad.append(f"{path.relative_to(PACKAGE.parent)}:{line}: {src} imports {target} ({dst})")
    assert not bad, "imports against the layers (docs/architecture.md):\n" + "\n".join(bad)
    assert used == set(EXCEPTIONS), f"exceptions no longer needed, remove them: {set(EXCEPTIONS) - used}"


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_cycle_between_packages() -> None:
    graph: dict[str, set[str]] = defaultdict(set)
    for name, path in _modules().items():
        if name in BASE or name == "omnibench.__main__":
            continue  # the root's own modules are the base layer (and the entry point)
        src = _package(name)
        for target, _ in _imports(name, path):
            if target in BASE or (name, target) in EXCEPTIONS:
                continue
            dst = _package(target)
            if dst != src:
                graph[src].add(dst)
    assert not _cycles(graph), f"packages importing each other: {_cycles(graph)}"


def test_no_private_name_is_imported_from_another_module() -> None:
    bad, used = [], set()
    for name, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not (isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("omnibench")):
                continue
            for a in node.names:
                if a.name.startswith("_") and not a.name.startswith("__"):
                    key = (name, f"{node.module}.{a.name}")
                    if key in PRIVATE_EXCEPTIONS:
                        used.add(key)
                    else:
                        bad.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: {node.module}.{a.name}")
    assert not bad, "private names imported across modules (make them public or move them):\n" + "\n".join(bad)
