"""What documents :class:`~encdesign.diagnose.FinderSettings`: the table of each field, its
default and its docstring (read from the class's source), as ``docs/diagnose.md`` carries it;
and the names of the acceptance rules (a field, or a rule that is not a threshold)."""

from __future__ import annotations

from ._settings import DEFAULT_SETTINGS, SETTINGS_FIELDS, FinderSettings

NAMED_RULES = ("identifiable", "better_candidate", "applies", "one_parameter_bic")
"""Acceptance rules that are not a threshold: all parameters already taken
(``identifiable``), another candidate lowers the criterion more (``better_candidate``), the
candidate cannot be tested on this record (``applies``), an alternative fits within one
parameter's information-criterion penalty ``log N`` and is confounded with it
(``one_parameter_bic``: sds, a drift vs an order of the platform angle); with
``<candidate>.plausible``."""


def is_rule_name(name: object) -> bool:
    """Whether ``name`` names an acceptance rule: a :class:`FinderSettings` field, one of
    :data:`NAMED_RULES`, or ``<candidate>.plausible``."""
    if not isinstance(name, str):
        return False
    if name in SETTINGS_FIELDS or name in NAMED_RULES:
        return True
    head, _, tail = name.rpartition(".")
    return tail == "plausible" and head.isidentifier()


_SOURCES = (
    ("_settings_selection.py", "AbstractSelectionSettings"),
    ("_settings.py", "FinderSettings"),
)
"""The files and classes that declare :class:`FinderSettings`' fields (its base first)."""


def _field_docs() -> dict[str, str]:
    """Each field's docstring (the string literal after its annotation), from the source of
    :class:`FinderSettings` and of its base (:data:`_SOURCES`)."""
    out: dict[str, str] = {}
    for file, name in _SOURCES:
        out.update(_class_field_docs(file, name))
    return out


def _class_field_docs(file: str, name: str) -> dict[str, str]:
    """The field docstrings of class ``name`` in ``file`` (beside this module)."""
    import ast
    from pathlib import Path

    tree = ast.parse((Path(__file__).parent / file).read_text(encoding="utf-8"))
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == name)
    out, last = {}, None
    for node in cls.body:
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            last = node.target.id
        elif (
            last
            and isinstance(node, ast.Expr)
            and isinstance(node.value, ast.Constant)
            and isinstance(node.value.value, str)
        ):
            out[last] = " ".join(node.value.value.split())
            last = None
        else:
            last = None
    return out


def settings_table(settings: FinderSettings = DEFAULT_SETTINGS) -> str:
    """The Markdown table of every threshold (field, default, what it controls and what
    evidence set it) that ``docs/diagnose.md`` carries between its
    ``<!-- settings-table -->`` markers."""
    docs = _field_docs()
    lines = ["| setting | default | what it controls; evidence |", "| --- | --- | --- |"]
    for name in SETTINGS_FIELDS:
        doc = docs.get(name, "").replace("|", "\\|")
        lines.append(f"| `{name}` | {getattr(settings, name)!r} | {doc} |")
    return "\n".join(lines) + "\n"
