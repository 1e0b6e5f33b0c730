"""The package's layout: imports point one way between subpackages and never form a circle.

Layers, lowest first (``docs/DEVELOPING.md``): the base modules (``_errors``, ``_progress``);
``physics``; ``io``; the tools ``design``, ``diagnose`` (and any later tool subpackage),
which never import each other; ``cli``; the public facades (``__init__``, ``objectives``).
A module may import its own subpackage and any lower layer. Every import counts, including
those inside functions: a lazy import hides a circle, it does not remove it.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parent.parent / "encdesign"

# subpackage (or top-level module) -> layer rank
LAYERS = {
    "_errors": 0,
    "_progress": 0,
    "_usercode": 0.5,  # base, above _errors (it raises the input error)
    "_checks": 0,
    "physics": 1,
    "io": 2,
    "design": 3,
    "diagnose": 3,
    "calibrate": 3,
    "cli": 4,
    "__init__": 5,
    "__main__": 5,
    "objectives": 5,
}


def _modules() -> dict[str, Path]:
    out = {}
    for f in PKG.rglob("*.py"):
        if "_bundled_studies" in f.parts:
            continue
        rel = f.relative_to(PKG).with_suffix("")
        out[".".join(rel.parts)] = f
    return out


def _resolve(mod: str, node: ast.ImportFrom) -> list[str]:
    """Absolute module names (under ``encdesign``) an ``ImportFrom`` node refers to."""
    base = mod.split(".")[:-1]  # the package the module sits in (for __init__: itself)
    if node.level:
        up = node.level - 1
        base = base[: len(base) - up] if up else base
        target = base + (node.module.split(".") if node.module else [])
    else:
        if not node.module or not node.module.startswith("encdesign"):
            return []
        target = node.module.split(".")[1:]
    names = [target] if node.module else []
    if not node.module or node.level:
        # ``from . import x`` / ``from .pkg import _mod``: the names may be modules
        names += [target + [a.name] for a in node.names]
    return [".".join(t) for t in names if t]


def _imports(mods: dict[str, Path]) -> dict[str, set[str]]:
    known = set(mods)

    def canon(name: str) -> str | None:
        if name in known:
            return name
        if f"{name}.__init__" in known:
            return f"{name}.__init__"
        return None

    graph: dict[str, set[str]] = {}
    for mod, path in mods.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                for t in _resolve(mod, node):
                    c = canon(t)
                    if c and c != mod:
                        deps.add(c)
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("encdesign."):
                        c = canon(a.name.split(".", 1)[1])
                        if c and c != mod:
                            deps.add(c)
        graph[mod] = deps
    return graph


def _layer(mod: str) -> str:
    return mod.split(".")[0]


def test_every_subpackage_has_a_layer():
    unknown = sorted({_layer(m) for m in _modules()} - set(LAYERS))
    assert not unknown, (
        f"subpackages/modules without a layer: {unknown}; add them to LAYERS in "
        "tests/test_layout.py and to the map in docs/DEVELOPING.md"
    )


def test_imports_point_down():
    graph = _imports(_modules())
    bad = []
    for mod, deps in graph.items():
        a = _layer(mod)
        for d in deps:
            b = _layer(d)
            if a == b:
                continue
            if LAYERS[b] >= LAYERS[a]:
                bad.append(f"{mod} imports {d} ({a} layer {LAYERS[a]} -> {b} layer {LAYERS[b]})")
    assert not bad, "upward or sideways imports:\n" + "\n".join(sorted(bad))


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
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


def test_no_import_circles():
    graph = _imports(_modules())
    # a package's __init__ re-exporting its own modules is not a circle of the design
    for mod in list(graph):
        if mod.endswith("__init__"):
            pkg = mod[: -len("__init__")]
            for d in graph:
                if d.startswith(pkg) and d != mod:
                    graph[d].discard(mod)
    cycles = _cycles(graph)
    assert not cycles, "import circles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


@pytest.mark.parametrize(
    "graph, expected",
    [
        ({"a": {"b"}, "b": {"a"}}, [["a", "b"]]),
        ({"a": {"b"}, "b": {"c"}, "c": set()}, []),
        ({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}, [["a", "b", "c"]]),
    ],
)
def test_cycle_finder_itself(graph, expected):
    assert _cycles(graph) == expected


def test_old_circles_would_be_caught():
    """The checker sees a lazy import inside a function (how two of the old circles hid)."""
    src = "def f():\n    from ._sds import mark_angles\n"
    node = next(n for n in ast.walk(ast.parse(src)) if isinstance(n, ast.ImportFrom))
    assert _resolve("physics._sds_errors", node) == ["physics._sds", "physics._sds.mark_angles"]
