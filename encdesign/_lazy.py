"""Public names of a package imported on first use (PEP 562 module ``__getattr__``).

A package's ``__init__`` lists its re-exports once, as ordinary ``from .x import Y as Y``
statements under ``if TYPE_CHECKING:`` (what type checkers and readers see), and ends with

    __getattr__, __dir__ = lazy_exports(__name__, __file__)

which reads that block (its syntax tree, once) and imports each name from its module when it
is first used: ``package.Y``, ``from package import Y`` and ``dir(package)`` work as with
eager imports, and ``import package`` costs only what the package itself needs. That is
what keeps ``encdesign diagnose`` from importing the design drivers' optimisers, the
bench simulators and the calibration code it never runs (``docs/scale.md``, "Start").
"""

from __future__ import annotations

import ast
import importlib
import sys
from collections.abc import Callable
from pathlib import Path


def _is_type_checking(test: ast.expr) -> bool:
    name = test.id if isinstance(test, ast.Name) else getattr(test, "attr", None)
    return isinstance(name, str) and name.lstrip("_") == "TYPE_CHECKING"


def exports_of(init_file: str | Path) -> dict[str, tuple[str, str]]:
    """``{public name: (relative module, attribute)}`` from the ``if TYPE_CHECKING:`` block(s)
    of a package's ``__init__`` (``from .x import Y as Z``: ``Z -> (".x", "Y")``;
    ``from . import sub``: ``sub -> (".", "sub")``)."""
    tree = ast.parse(Path(init_file).read_text(encoding="utf-8"))
    table: dict[str, tuple[str, str]] = {}
    for node in tree.body:
        if not (isinstance(node, ast.If) and _is_type_checking(node.test)):
            continue
        for imp in node.body:
            if isinstance(imp, ast.ImportFrom) and imp.level > 0:
                base = "." * imp.level + (imp.module or "")
                for a in imp.names:
                    table[a.asname or a.name] = (base, a.name)
    return table


def lazy_exports(
    package: str, init_file: str
) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for package ``package`` whose ``__init__`` is
    ``init_file``: each name of :func:`exports_of` is imported on first use and then kept
    in the package's namespace (later uses cost nothing)."""
    table = exports_of(init_file)

    def __getattr__(name: str) -> object:
        got = table.get(name)
        if got is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        base, attr = got
        if base.strip(".") == "":  # from . import sub
            value: object = importlib.import_module(f"{base}{attr}", package)
        else:
            module = importlib.import_module(base, package)
            try:
                value = getattr(module, attr)
            except AttributeError:  # from .x import submodule
                value = importlib.import_module(f"{base}.{attr}", package)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted({*vars(sys.modules[package]), *table})

    return __getattr__, __dir__
